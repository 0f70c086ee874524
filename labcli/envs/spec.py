"""What a task plugin registers: a `TaskSpec` naming the task's code, its pydantic config and its
MuJoCo model (an MJCF file, or a robot of MuJoCo Menagerie by name: `Menagerie`). Importing this
module imports neither torch, MuJoCo nor pydantic: `lab list` and shell completion read specs
without building anything."""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from labcli import refs


@dataclass(frozen=True)
class Menagerie:
    """A model of MuJoCo Menagerie: a robot's folder and one of its entry points (an MJCF
    that compiles on its own), e.g. `Menagerie("unitree_g1", "scene_mjx")`. The
    `mujoco-menagerie` package downloads the folder on first use (labcli/envs/models.py)."""

    robot: str
    entry: str

    def __str__(self) -> str:
        return f"menagerie:{self.robot}/{self.entry}"


@dataclass(frozen=True)
class TaskSpec:
    """A task's name, code, config, model and per-framework defaults. `task` and `config` are the
    classes, or "module:Class" strings imported when first used (`task_class`, `config_class`),
    so that a plugin module that registers a task need not import torch."""

    name: str
    task: type | str  # a labcli.envs.task.Task subclass
    config: type | str  # a labcli.envs.config.TaskConfig subclass
    model: Path | Menagerie
    description: str = ""
    success: str = ""
    # framework name -> {"env": {...}, "agent": {...}} overrides, like Isaac Lab's agents/*_cfg.
    framework_defaults: Mapping[str, Mapping[str, Mapping[str, Any]]] = field(default_factory=dict)

    @functools.cached_property
    def task_class(self) -> type:
        return refs.resolve(self.task, f"task '{self.name}'")

    @functools.cached_property
    def config_class(self) -> type:
        return refs.resolve(self.config, f"task '{self.name}'")

    def lazy_refs(self) -> tuple[Any, ...]:
        """The references `lab list` checks for a module that cannot be found."""
        return self.task, self.config
