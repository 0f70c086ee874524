"""Action terms: how actions in [-1, 1] become `ctrl`, per actuator."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

import torch

from labcli.envs.mdp import config as c
from labcli.envs.mdp import names, robot_model
from labcli.errors import LabError

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask


def per_actuator(task: RobotTask, scale: float | dict[str, float] | None) -> list[float]:
    """Each actuator's scale: one number for all, the first pattern matching its name, or
    (None) its joint's in the robot description."""
    if scale is None:
        if task.cfg.robot is None:
            raise LabError("env.actions.scale is null and the task has no robot description "
                           "to take each joint's from", "give env.actions.scale a number")
        return robot_model.action_scales(task.cfg.robot, task.robot.joint_names)
    actuators = names.all_names(task.model, "actuator")
    if not isinstance(scale, dict):
        return [float(scale)] * len(actuators)
    values = []
    for name in actuators:
        match = next((v for p, v in scale.items() if re.fullmatch(p, name)), None)
        if match is None:
            raise LabError(f"no action scale pattern matches actuator '{name}'",
                           f"add a pattern for it to env.actions.scale ({sorted(scale)})")
        values.append(float(match))
    return values


class JointEffortAction:
    def __init__(self, task: RobotTask, cfg: c.JointEffort):
        self.scale = task.tiled(per_actuator(task, cfg.scale))
        self.offset: torch.Tensor | None = None
        self.commands = [f"ctrl = {s:g} * action" for s in self.scale[0].tolist()]

    def __call__(self, actions: torch.Tensor, ctrl: torch.Tensor) -> None:
        torch.mul(actions, self.scale, out=ctrl)
        if self.offset is not None:
            ctrl.add_(self.offset)


class JointPositionAction(JointEffortAction):
    def __init__(self, task: RobotTask, cfg: c.JointPosition):
        super().__init__(task, cfg)
        self.offset = task.robot.default_joint_pos
        self.commands = [f"ctrl = {d:g} + {s:g} * action" for d, s in
                         zip(self.offset[0].tolist(), self.scale[0].tolist(), strict=True)]
