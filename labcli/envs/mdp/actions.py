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


class ActuatorDelay:
    """Each env's controls reaching its motors `lag` physics steps late, `lag` drawn per env at
    every episode's start from `lags` (inclusive).

    The controls the policy sent at the last few env steps are kept, newest first; physics step
    k (0 <= k < decimation) of a step applies the newest of them sent at least `lag` physics
    steps before it: the one sent ceil((lag - k) / decimation) env steps ago. An env's first
    control of an episode stands for the ones before it. `controls` holds each physics step's
    `[decimation, num_envs, nu]`, for the sim."""

    carried = ("history", "lag", "fresh")

    def __init__(self, task: RobotTask, lags: tuple[int, int]):
        n, nu, steps = task.num_envs, task.model.nu, task.cfg.decimation
        dev, dtype = task.action.device, task.sim.ctrl.dtype
        self.task, self.low, self.count = task, lags[0], lags[1] - lags[0] + 1
        # Envs first, as all state a task carries (an env shard's is its rows).
        self.history = torch.zeros(n, -(-lags[1] // steps) + 1, nu, dtype=dtype, device=dev)
        self.lag = torch.zeros(n, dtype=torch.long, device=dev)
        self.fresh = torch.ones(n, dtype=torch.bool, device=dev)
        self.controls = torch.zeros(steps, n, nu, dtype=dtype, device=dev)
        self.substep = torch.arange(steps, device=dev)[:, None]
        self.envs = torch.arange(n, device=dev)[None, :]
        self.draw = torch.empty(n, device=dev)

    def reset(self, mask: torch.Tensor) -> None:
        self.task.rng.uniform_(self.draw)
        lag = self.draw.mul(self.count).long().clamp_(max=self.count - 1).add_(self.low)
        torch.where(mask, lag, self.lag, out=self.lag)
        self.fresh.logical_or_(mask)

    def __call__(self, ctrl: torch.Tensor) -> None:
        """`ctrl`, the controls just sent, into the history and `controls`."""
        self.history.copy_(self.history.roll(1, dims=1))
        self.history[:, 0] = ctrl
        torch.where(self.fresh[:, None, None], ctrl[:, None, :], self.history, out=self.history)
        self.fresh.zero_()
        back = (self.lag - self.substep).add_(self.controls.shape[0] - 1)
        back = back.div_(self.controls.shape[0], rounding_mode="floor")
        self.controls.copy_(self.history[self.envs, back])


class JointEffortAction:
    def __init__(self, task: RobotTask, cfg: c.JointEffort):
        self.scale = task.tiled(per_actuator(task, cfg.scale))
        self.robot = task.robot
        self.offset: torch.Tensor | None = None
        self.binary: Binary | None = None
        self.commands = [f"ctrl = {s:g} * action" for s in self.scale[0].tolist()]
        self.delay = ActuatorDelay(task, cfg.delay) if cfg.delay is not None else None

    def __call__(self, actions: torch.Tensor, ctrl: torch.Tensor) -> None:
        torch.mul(actions, self.scale, out=ctrl)
        if self.offset is not None:
            ctrl.add_(self.offset)
            if self.robot.biased:  # the servo aims where its biased encoder reads the target
                ctrl.sub_(self.robot.encoder_bias)
        if self.binary is not None:
            self.binary(actions, ctrl)
        if self.delay is not None:
            self.delay(ctrl)


class Binary:
    """The actuators of `cfg` (a gripper) at `open` where their action is >= 0, else `close`."""

    def __init__(self, task: RobotTask, cfg: c.BinaryJoints):
        self.actuators = names.resolve(task.model, "actuator", cfg.actuators)
        self.cfg = cfg
        self.index = torch.tensor(self.actuators, device=task.ones.device)
        width = len(self.actuators)
        self.open = task.tiled([cfg.open] * width)
        self.close = task.tiled([cfg.close] * width)

    def __call__(self, actions: torch.Tensor, ctrl: torch.Tensor) -> None:
        closing = actions.index_select(1, self.index) < 0.0
        ctrl.index_copy_(1, self.index, torch.where(closing, self.close, self.open))


class JointPositionAction(JointEffortAction):
    def __init__(self, task: RobotTask, cfg: c.JointPosition):
        super().__init__(task, cfg)
        self.offset = task.robot.default_joint_pos
        self.commands = [f"ctrl = {d:g} + {s:g} * action" for d, s in
                         zip(self.offset[0].tolist(), self.scale[0].tolist(), strict=True)]
        if cfg.binary is not None:
            self.binary = Binary(task, cfg.binary)
            for i in self.binary.actuators:
                self.commands[i] = (f"ctrl = {cfg.binary.open:g} if action >= 0, else "
                                    f"{cfg.binary.close:g}")
