"""What a task plugin registers: a `TaskSpec` naming the task's code, its pydantic config and its
MJCF model. Importing this module imports neither torch nor MuJoCo: `lab list`, shell completion
and `lab config show` read specs without building anything."""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, Field

from labcli import refs

if TYPE_CHECKING:
    from labcli.envs.task import Task


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


@dataclass(frozen=True)
class TaskSpec:
    """A task's name, code, config, model and per-framework defaults. `task` and `config` are the
    classes, or "module:Class" strings imported when first used (`task_class`, `config_class`),
    so that a plugin module that registers a task need not import torch."""

    name: str
    task: type[Task] | str
    config: type[TaskConfig] | str
    model: Path
    description: str = ""
    success: str = ""
    # framework name -> {"env": {...}, "agent": {...}} overrides, like Isaac Lab's agents/*_cfg.
    framework_defaults: Mapping[str, Mapping[str, Mapping[str, Any]]] = field(default_factory=dict)

    @functools.cached_property
    def task_class(self) -> type[Task]:
        return refs.resolve(self.task, f"task '{self.name}'")

    @functools.cached_property
    def config_class(self) -> type[TaskConfig]:
        return refs.resolve(self.config, f"task '{self.name}'")

    def lazy_refs(self) -> tuple[Any, ...]:
        """The references `lab list` checks for a module that cannot be found."""
        return self.task, self.config
