"""The public task API: a pydantic config, an MJCF model and batched torch functions over a Sim.

A task is written once with torch operations on `[num_envs, ...]` tensors, so it runs unchanged
on every backend. Plugins register a `TaskSpec` from their `register_tasks` hook.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import torch
from pydantic import BaseModel, ConfigDict, Field

if TYPE_CHECKING:
    from labcli.env import LabVecEnv
    from labcli.sim import Sim


class TaskConfig(BaseModel):
    """Settings every task has; a task subclasses it to add its own (reset ranges, bounds...)."""

    # NaN and inf are never meant: they would only surface later as a diverged run.
    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)

    # The upper bounds are far beyond any use; past them a typo would exhaust memory or overflow
    # the step count instead of failing at once.
    num_envs: int = Field(64, gt=0, le=2**20, description="parallel environments")
    episode_length_s: float = Field(5.0, gt=0, le=1e6, description="time-out, in seconds")
    decimation: int = Field(2, gt=0, le=1000, description="physics steps per env step")
    sim_dt: float | None = Field(None, gt=0, description="physics step; None keeps the MJCF's")
    action_scale: float = Field(1.0, description="policy action in [-1, 1] times this is ctrl")
    reward_weights: dict[str, float] = Field(default_factory=dict)
    threads: int | None = Field(None, gt=0, le=4096, description="cpu backend: threads that "
                                "step the physics (None: the cores this process may use)")
    cuda_graph: bool = Field(True, description="on a GPU, replay each env step as one CUDA graph "
                             "(false: step eagerly, for debugging a task)")


class Task:
    """Batched MDP terms over `sim`; subclasses override the methods below with torch code."""

    observation_names: ClassVar[list[str]]
    action_names: ClassVar[list[str]]

    def __init__(self, cfg: TaskConfig, sim: Sim):
        self.cfg = cfg
        self.sim = sim

    def apply_actions(self, actions: torch.Tensor) -> None:
        """Turn clipped actions in [-1, 1] into controls; the default scales them into ctrl."""
        torch.mul(actions, self.cfg.action_scale, out=self.sim.ctrl)

    def update(self) -> None:
        """Called by the env each time the sim's state changed (after the physics steps, a reset
        or a restore), before it reads any term: compute here, once, what several terms share
        (cartpole: the wrapped pole angle), instead of once per term. Write the results into
        tensors made once (`out=`, in-place ops): on a GPU the env step replays as a CUDA graph,
        which writes into the tensors it was captured with. The default does nothing."""

    def observations(self) -> torch.Tensor:
        raise NotImplementedError

    def reward_terms(self) -> dict[str, torch.Tensor]:
        """Unweighted reward terms by name; the weights come from `cfg.reward_weights`."""
        raise NotImplementedError

    def terminations(self) -> dict[str, torch.Tensor]:
        """Boolean `[num_envs]` per termination cause (time-outs are the env's business)."""
        return {}

    def reset(self, mask: torch.Tensor, generator: torch.Generator) -> None:
        """Randomize the state of the envs in `mask`; the sim already put them at the defaults."""

    def success(self, time_out: torch.Tensor) -> torch.Tensor:
        """Whether each ending episode succeeded, judged on its final state."""
        return torch.zeros_like(time_out)


@dataclass(frozen=True)
class TaskSpec:
    """What a plugin registers: a task's name, code, config, model and per-framework defaults."""

    name: str
    task: type[Task]
    config: type[TaskConfig]
    model: Path
    description: str = ""
    success: str = ""
    # framework name -> {"env": {...}, "agent": {...}} overrides, like Isaac Lab's agents/*_cfg.
    framework_defaults: Mapping[str, Mapping[str, Mapping[str, Any]]] = field(default_factory=dict)

    def make_env(self, cfg: TaskConfig, *, backend: str | None = None, device: str = "cpu",
                 seed: int = 0) -> LabVecEnv:
        """The batched env of this task; other kinds of task (gymnasium's) build their own."""
        from labcli.env import LabVecEnv

        return LabVecEnv(self, cfg, backend=backend, device=device, seed=seed)
