"""The public framework-plugin API: what a learning library provides to `lab`.

A framework plugin registers a `FrameworkSpec`: its name, agent config, checkpoint file names,
wrappers (its adapter first), defaults for tasks it knows and, by a "module:Class" reference
imported only when training or loading, its `Framework` subclass (`train`, `load_policy`,
`pipeline`). Every framework runs under the same `lab train/play/export` commands and the same
run layout. Nothing here imports torch, pydantic or a learning library: listing stays instant.
The agent's settings are an `AgentConfig` (labcli/plugins/config.py). docs/plugins.md is the
reference of this API.
"""

from __future__ import annotations

import abc
import contextlib
import functools
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from labcli import refs
from labcli.envs.wrappers import Stage, Step, WrapperSpec

# A checkpoint's writer: `save(path)` writes the framework's model file at exactly `path`, whose
# name is the final one (`model_50.pt`) in a private staging directory, and its companions
# beside it in `path.parent`. A library that appends the suffix itself is handed
# `path.with_suffix("")`.
Save = Callable[[Path], None]
# The live agent's deterministic action (the mean, before any clipping) for a batch of the env's
# raw observations, computed the library's own way: its normalizer, its forward pass.
Actor = Callable[[Any], Any]


class StopTraining(Exception):
    """Training must end now: raised by the env's `step` once a stop is requested (Ctrl-C,
    SIGTERM), and by a framework's own hook when `end_iteration` returns True, to leave a loop
    the library owns. `TrainContext.training` catches it and checkpoints."""


@dataclass
class Checkpoint:
    path: Path
    iteration: int


@dataclass(frozen=True)
class FrameworkSpec:
    """What a framework plugin registers. `framework` and `agent_config` are classes or
    "module:Class" strings imported when first used. `wrappers` are the wrappers the framework
    owns, its `Stage.ADAPTER` first; lab registers them with the framework. `library` is the
    distribution of the learning library (its version shows in `lab info` and each run's
    manifest). `task_defaults` are this framework's defaults for tasks it knows, task name ->
    {"env": {...}, "agent": {...}}; a task's own `framework_defaults` for this framework win
    over them. Checkpoint files are `<checkpoint_prefix><iteration><checkpoint_suffix>` in the
    run dir, e.g. model_50.zip."""

    name: str
    framework: type[Framework] | str
    agent_config: type | str  # a labcli.plugins.config.AgentConfig subclass
    wrappers: Sequence[WrapperSpec] = ()
    description: str = ""
    library: str = ""
    task_defaults: Mapping[str, Mapping[str, Mapping[str, Any]]] = field(default_factory=dict)
    checkpoint_prefix: str = "model_"
    checkpoint_suffix: str = ".pt"
    # Companions only a run's newest checkpoint keeps, by file-name prefix, and what each is
    # (e.g. {"memory_": "replay memory"}): large, and needed only to resume exactly. An older
    # checkpoint loses them once a newer one is written; it still plays, exports and resumes,
    # without them.
    newest_only: Mapping[str, str] = field(default_factory=dict)
    # Trains on several ranks (torchrun, `lab train --nproc`): the library averages gradients
    # over torch.distributed's default group and keeps its normalizers equal on every rank.
    data_parallel: bool = False
    # Its critic reads a task's own critic observations (`info["critic_obs"]` of the env's reset
    # and steps) where the task gives them; without, lab says the critic reads the policy's.
    critic_observations: bool = False

    @functools.cached_property
    def agent_config_class(self) -> type:
        return refs.resolve(self.agent_config, f"framework '{self.name}'")

    @functools.cached_property
    def adapter(self) -> WrapperSpec | None:
        return next((w for w in self.wrappers if w.stage is Stage.ADAPTER), None)

    def lazy_refs(self) -> tuple[Any, ...]:
        """The references `lab list` checks for a module that cannot be found."""
        return self.framework, self.agent_config, *(w.build for w in self.wrappers)

    def load(self) -> Framework:
        """The implementation, imported and made now."""
        cls = refs.resolve(self.framework, f"framework '{self.name}'")
        return cls(self)

    def checkpoint_path(self, run_dir: Path, iteration: int) -> Path:
        return run_dir / f"{self.checkpoint_prefix}{iteration}{self.checkpoint_suffix}"

    def checkpoints(self, run_dir: Path) -> list[Checkpoint]:
        """Checkpoint files in `run_dir` by name, oldest first (complete or not: see
        labcli/runs/checkpoints.py)."""
        pattern = re.compile(re.escape(self.checkpoint_prefix) + r"(\d+)"
                             + re.escape(self.checkpoint_suffix) + "$")
        try:
            paths = list(run_dir.glob(f"{self.checkpoint_prefix}*{self.checkpoint_suffix}"))
        except FileNotFoundError:
            # Deleted between glob's check and its listing: none, as glob says of a missing
            # dir (the deleted run is said where it is written to).
            paths = []
        found = [Checkpoint(path, int(match.group(1))) for path in paths
                 if (match := pattern.match(path.name))]
        return sorted(found, key=lambda c: c.iteration)


class Framework:
    """Base class of a framework's implementation, made from its spec by `FrameworkSpec.load`.
    Subclasses override `train` and `load_policy`, and `pipeline` where the config adds
    framework-stage wrappers."""

    def __init__(self, spec: FrameworkSpec):
        self.spec = spec

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def agent_config(self) -> type:
        return self.spec.agent_config_class

    def pipeline(self, cfg: Any) -> list[Step]:
        """The adapter and framework-stage wrappers to train with under `cfg`; by default the
        adapter alone."""
        return [Step(self.spec.adapter)] if self.spec.adapter else []

    def train(self, env: Any, ctx: TrainContext) -> None:
        """Train on the wrapped `env` until `ctx.cfg.max_iterations`, inside
        `with ctx.training(save):`, calling `ctx.end_iteration(..., save)` after each update.
        Once a stop is requested the env's next step raises `StopTraining`, which
        `ctx.training` catches. On resume (`ctx.resume`), load the checkpoint, then call
        `ctx.restore_rng()` right before the first rollout."""
        raise NotImplementedError

    def load_policy(self, checkpoint: Path, env: Any, cfg: Any) -> Any:
        """Load `checkpoint` as a `labcli.plugins.policy.Policy` for `env`'s observation and
        action spaces. `cfg` is the agent config the run trained with (its params/agent.yaml):
        what rebuilds the networks where a checkpoint holds only their tensors. A checkpoint is
        data: load tensors with `torch.load(weights_only=True)`, never unpickle objects."""
        raise NotImplementedError


class TrainContext(abc.ABC):
    """What a framework's `train(env, ctx)` is handed besides the env: the config, the run dir,
    and the calls that keep logging, progress, checkpoints and Ctrl-C the same for every
    library. lab implements it (labcli/runs/context.py); a plugin only uses it."""

    cfg: Any  # the resolved agent config, an instance of the spec's AgentConfig subclass
    env: Any  # the unwrapped env (a LabVecEnv, or the gymnasium bridge)
    run_dir: Path
    seed: int
    device: str  # torch device of the env and the learner
    writer: Any  # the run's TensorBoard SummaryWriter, for the library's own figures
    resume: Checkpoint | None  # the checkpoint a resumed run starts from
    # The agent settings this resume changed (e.g. {"learning_rate"}): the config has their new
    # values; apply them over what the checkpoint restores (an optimizer's saved learning rate).
    changed: frozenset[str]
    iteration: int  # iterations done, counted on from a resumed checkpoint
    steps: int  # env steps done, likewise (of all ranks)
    # A data-parallel run: this process's rank among `world_size`. torch.distributed's default
    # process group is set up (gloo on the CPU, NCCL on GPUs) before the framework's code is
    # imported; each rank trains on its own `env`. Only rank 0 writes: elsewhere `writer` drops
    # what it is given and `save` writes nothing (but must still be called on every rank).
    rank: int
    world_size: int
    # Figures whose names are the TensorBoard tags of labcli.envs.metrics.
    last_stats: Mapping[str, float]
    # Torch threads for the learner's update on the CPU (`torch_threads(device, update_threads)`
    # of labcli.plugins.policy around it; the rest of training runs on one): half the cores this
    # run's physics may use. The physics threads sleep during an update, and its mini-batches
    # are large enough to pay for threads.
    update_threads: int

    @property
    def start_iteration(self) -> int:
        """The iteration training starts after: the resumed checkpoint's, 0 for a new run."""
        return self.resume.iteration if self.resume else 0

    @property
    @abc.abstractmethod
    def stop_requested(self) -> bool:
        """SIGINT or SIGTERM arrived: the env's next step raises `StopTraining`."""

    @contextlib.contextmanager
    def training(self, save: Save) -> Iterator[None]:
        """Around the library's training loop: `StopTraining` ends the loop, and the last
        complete iteration is checkpointed through `save` (once: an iteration `end_iteration`
        saved already is not written again)."""
        with contextlib.suppress(StopTraining):
            yield
        self.save(save)

    @abc.abstractmethod
    def restore_rng(self) -> None:
        """On resume, put the random generators back where the checkpoint's iteration left
        them; call it once the agent is built, right before the first rollout."""

    @abc.abstractmethod
    def end_iteration(self, iteration: int, steps: int, save: Save,
                      scalars: Mapping[str, float] | None = None, *,
                      last_good: Save | None = None) -> bool:
        """After each rollout + update: `iteration` and `steps` (this rank's env's) done so
        far, counted on from a resumed checkpoint; `scalars` are the library's own figures
        (losses) by TensorBoard tag. Logs the common figures, updates progress, checkpoints
        through `save` when due. Returns True when training must end now: `max_iterations` is
        reached or a stop was requested (on any rank); the checkpoint is written then.
        `last_good`: a lighter `save` for the state kept after every iteration between
        checkpoints (a run that diverges ends with it), where `save` also writes what only an
        exact resume needs and costs more than an iteration should (a replay memory)."""

    @abc.abstractmethod
    def save(self, save: Save) -> None:
        """Checkpoint the current iteration (`self.iteration`) through `save`, atomically;
        nothing when that iteration is saved already. A library's own counters may include a
        rollout dropped by a stop: `save` writes `self.iteration` and `self.steps`."""

    @abc.abstractmethod
    def watch(self, *networks: Any) -> None:
        """The agent's networks (torch modules), checked for NaN and inf after each update."""

    @abc.abstractmethod
    def set_actor(self, actor: Actor) -> None:
        """The live agent's deterministic actions (see `Actor`). At each checkpoint lab loads
        the Policy `load_policy` makes of it and checks that it acts the same on the env's
        current observations: what is played and exported is what was trained. The conformance
        suite requires it."""
