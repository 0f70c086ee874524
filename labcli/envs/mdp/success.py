"""Success terms: judged on an episode's final state at its time-out, `[num_envs]` booleans."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from labcli.envs.mdp import config as c
from labcli.envs.mdp.observations import direction_to_target

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask


class moved_toward_target:  # noqa: N801
    """How far the root moved toward the target since its episode began, horizontally."""

    carried = ("start",)

    def __init__(self, task: RobotTask, cfg: c.MovedTowardTarget):
        self.task, self.cfg = task, cfg
        self.start = task.robot.root_xy.clone()

    def reset(self, mask: torch.Tensor) -> None:
        torch.where(mask[:, None], self.task.robot.root_xy, self.start, out=self.start)

    def __call__(self) -> torch.Tensor:
        moved = (self.task.robot.root_xy - self.start) * direction_to_target(self.task,
                                                                             self.cfg.target)
        return moved.sum(dim=1) >= self.cfg.distance


class tracked_command:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.TrackedCommand):
        self.command, self.cfg = task.command(cfg.command), cfg

    def __call__(self) -> torch.Tensor:
        errors = self.command.mean_errors
        return ((errors[:, 0] < self.cfg.lin_vel_error)
                & (errors[:, 1] < self.cfg.ang_vel_error))


class pose_reached:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.PoseReached):
        self.command, self.cfg = task.command(cfg.command), cfg

    def __call__(self) -> torch.Tensor:
        errors = self.command.errors  # the step's, against the command it pursued
        reached = errors[:, 0] < self.cfg.position_error
        if self.cfg.orientation_error is not None:
            reached &= errors[:, 1] < self.cfg.orientation_error
        return reached
