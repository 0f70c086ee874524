"""The public framework-plugin API: what a learning library provides to `lab`.

A framework plugin registers a `FrameworkSpec`: its name, agent config, checkpoint file names,
wrappers (its adapter first) and, by a "module:Class" reference imported only when training or
loading, its `Framework` subclass (`train`, `load_policy`, `pipeline`). Every framework runs
under the same `lab train/play/export` commands and the same run layout. Nothing here imports
torch, pydantic or a learning library: listing stays instant. The agent's settings are an
`AgentConfig` (labcli/plugins/config.py).
"""

from __future__ import annotations

import abc
import functools
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from labcli import refs
from labcli.envs.wrappers import Stage, Step, WrapperSpec


@dataclass
class Checkpoint:
    path: Path
    iteration: int


@dataclass(frozen=True)
class FrameworkSpec:
    """What a framework plugin registers. `framework` and `agent_config` are classes or
    "module:Class" strings imported when first used. `wrappers` are the wrappers the framework
    owns, its `Stage.ADAPTER` first; lab registers them with the framework. Checkpoint files are
    `<checkpoint_prefix><iteration><checkpoint_suffix>` in the run dir, e.g. model_50.zip."""

    name: str
    framework: type[Framework] | str
    agent_config: type | str  # a labcli.plugins.config.AgentConfig subclass
    wrappers: Sequence[WrapperSpec] = ()
    description: str = ""
    checkpoint_prefix: str = "model_"
    checkpoint_suffix: str = ".pt"

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
        found = []
        for path in run_dir.glob(f"{self.checkpoint_prefix}*{self.checkpoint_suffix}"):
            match = pattern.match(path.name)
            if match:
                found.append(Checkpoint(path, int(match.group(1))))
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
        """Train on the wrapped `env` until `ctx.cfg.max_iterations`, calling
        `ctx.end_iteration` after each iteration and `ctx.save` for checkpoints, stopping at the
        next env step once `ctx.stop_requested`. On resume (`ctx.resume`), load the checkpoint,
        then call `ctx.restore_rng()` right before the first rollout."""
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
    steps: int  # env steps done, likewise
    # Figures whose names are the TensorBoard tags of labcli.envs.metrics.
    last_stats: Mapping[str, float]

    @property
    def start_iteration(self) -> int:
        """The iteration training starts after: the resumed checkpoint's, 0 for a new run."""
        return self.resume.iteration if self.resume else 0

    @property
    @abc.abstractmethod
    def stop_requested(self) -> bool:
        """SIGINT or SIGTERM arrived: stop at the next env step; lab takes care of the
        checkpoint."""

    @abc.abstractmethod
    def restore_rng(self) -> None:
        """On resume, put the random generators back where the checkpoint's iteration left
        them; call it once the agent is built, right before the first rollout."""

    @abc.abstractmethod
    def end_iteration(self, iteration: int, steps: int, save: Callable[[Path], None],
                      scalars: Mapping[str, float] | None = None) -> bool:
        """Log the common figures, update progress, checkpoint when due. Returns True when
        training must stop now; the checkpoint is already written then."""

    @abc.abstractmethod
    def save(self, save: Callable[[Path], None]) -> None:
        """Checkpoint the current iteration through `save(path)`, atomically; nothing when that
        iteration is saved already."""

    @abc.abstractmethod
    def watch(self, *networks: Any) -> None:
        """The agent's networks (torch modules), checked for NaN and inf after each update."""
