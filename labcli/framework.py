"""The public framework-plugin API: what a learning library provides to `lab`.

A framework plugin registers one `Framework` instance (its name, agent config, wrappers,
`train`, `load_policy`) and the wrappers it builds on (its adapter first). Every framework
runs under the same `lab train/play/export` commands and the same run layout.
"""

from __future__ import annotations

import contextlib
import re
import zipfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import torch
from pydantic import BaseModel, ConfigDict, Field
from torch import nn

from labcli.wrappers import Step, WrapperSpec

if TYPE_CHECKING:
    from labcli.env import LabVecEnv
    from labcli.training import TrainContext


class AgentConfig(BaseModel):
    """Settings every framework has; a plugin subclasses it with its library's hyperparameters."""

    # NaN and inf are never meant: they would only surface later as a diverged run.
    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)

    max_iterations: int = Field(100, gt=0, description="rollout + update cycles in total")
    save_interval: int = Field(50, gt=0, description="iterations between checkpoints")
    seed: int = Field(0, ge=0, lt=2**32, description="seeds the env, torch, NumPy and Python")


class ObsNormalizer(nn.Module):
    """(obs - mean) / sqrt(var + eps), clipped: the frozen form of a running normalizer."""

    def __init__(self, mean: torch.Tensor, var: torch.Tensor, eps: float, clip: float | None):
        super().__init__()
        self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float32).clone())
        self.register_buffer("std", torch.sqrt(torch.as_tensor(var, dtype=torch.float32) + eps))
        self.clip = clip

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        out = (obs - self.mean) / self.std
        return out if self.clip is None else out.clamp(-self.clip, self.clip)


class Policy(nn.Module):
    """Observation → deterministic action in [-1, 1], with the observation normalizer inside,
    so that what is played and exported is exactly what was trained."""

    def __init__(self, actor: nn.Module, normalizer: nn.Module | None = None):
        super().__init__()
        self.normalizer = normalizer if normalizer is not None else nn.Identity()
        self.actor = actor

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.actor(self.normalizer(obs)).clamp(-1.0, 1.0)


@contextlib.contextmanager
def one_torch_thread(device: str) -> Iterator[None]:
    """On CPU, run the learner on one torch thread. Policy-sized MLPs gain nothing from more:
    they only add synchronization, and their spinning threads fight MuJoCo's for the cores
    (measured on 2 cores: 6 RSL-RL cartpole iterations took 28 s with 2 threads, 2 s with 1;
    an skrl backward pass 44 ms against 1 ms)."""
    if torch.device(device).type != "cpu":
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


ZIP_SUFFIXES = (".zip", ".pt", ".pth")


@dataclass
class Checkpoint:
    path: Path
    iteration: int


class Framework:
    """Base class of framework plugins. Subclasses set the class attributes and override
    `pipeline`, `train` and `load_policy`."""

    name: ClassVar[str]
    description: ClassVar[str] = ""
    agent_config: ClassVar[type[AgentConfig]] = AgentConfig
    # Checkpoint files are `<prefix><iteration><suffix>` in the run dir, e.g. model_50.zip.
    checkpoint_prefix: ClassVar[str] = "model_"
    checkpoint_suffix: ClassVar[str] = ".pt"

    def wrappers(self) -> Sequence[WrapperSpec]:
        """The wrappers this framework owns (its adapter first); registered with the plugin."""
        return ()

    def pipeline(self, cfg: AgentConfig) -> list[Step]:
        """The adapter and framework-stage wrappers to train with under `cfg`."""
        raise NotImplementedError

    def train(self, env: object, ctx: TrainContext) -> None:
        """Train on the wrapped `env` until `ctx.cfg.max_iterations`, calling
        `ctx.end_iteration` after each iteration and `ctx.save` for checkpoints, stopping at the
        next env step once `ctx.stop_requested`. On resume (`ctx.resume`), load the checkpoint,
        then call `ctx.restore_rng()` right before the first rollout."""
        raise NotImplementedError

    def load_policy(self, checkpoint: Path, env: LabVecEnv) -> Policy:
        """Load `checkpoint` as a Policy for `env`'s observation and action spaces."""
        raise NotImplementedError

    def checkpoint_path(self, run_dir: Path, iteration: int) -> Path:
        return run_dir / f"{self.checkpoint_prefix}{iteration}{self.checkpoint_suffix}"

    def checkpoint_complete(self, path: Path) -> bool:
        """Whether `path` reads back whole. SB3's .zip and torch.save's .pt are zip containers,
        whose checksums tell a truncated or damaged file; other formats are taken as they are
        (a plugin with one overrides this)."""
        try:
            with zipfile.ZipFile(path) as archive:
                return archive.testzip() is None
        except (zipfile.BadZipFile, OSError, EOFError):
            return path.suffix not in ZIP_SUFFIXES and path.is_file()

    def latest_checkpoint(self, run_dir: Path) -> Checkpoint | None:
        """The newest complete checkpoint in `run_dir`: a truncated or damaged newer file (copied
        half-way, written by an older lab without renames) is passed over."""
        for found in reversed(self.checkpoints(run_dir)):
            if self.checkpoint_complete(found.path):
                return found
        return None

    def checkpoints(self, run_dir: Path) -> list[Checkpoint]:
        """Complete checkpoints in `run_dir`, oldest first (they are written by rename)."""
        pattern = re.compile(re.escape(self.checkpoint_prefix) + r"(\d+)"
                             + re.escape(self.checkpoint_suffix) + "$")
        found = []
        for path in run_dir.glob(f"{self.checkpoint_prefix}*{self.checkpoint_suffix}"):
            match = pattern.match(path.name)
            if match:
                found.append(Checkpoint(path, int(match.group(1))))
        return sorted(found, key=lambda c: c.iteration)


@dataclass
class TrainResult:
    iterations: int
    steps: int
    interrupted: bool = False
    stats: dict[str, float] = field(default_factory=dict)
