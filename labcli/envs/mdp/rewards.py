"""Reward terms, unweighted (the weight is the term's config): each a function of the task
returning `[num_envs]`, or a class made once per task. Names follow Isaac Lab's `mdp`."""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import torch

from labcli.envs.mdp import config as c
from labcli.envs.mdp import sensors
from labcli.envs.mdp.observations import distance_to_target, heading_projection

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask


def is_alive(task: RobotTask, cfg: c.Alive) -> torch.Tensor:
    # A terminated env earns its last step's reward too (the env zeroes only unstable ones).
    return task.ones


class progress_reward:  # noqa: N801 - a term, named as Isaac Lab's
    """The potential -distance/dt to the target after the step minus before it."""

    def __init__(self, task: RobotTask, cfg: c.Progress):
        self.task, self.target = task, cfg.target
        self.before = torch.zeros_like(task.ones)

    def potential(self) -> torch.Tensor:
        return distance_to_target(self.task, self.target) / -self.task.step_dt

    def pre_physics(self) -> None:
        self.before.copy_(self.potential())

    def __call__(self) -> torch.Tensor:
        return self.potential() - self.before


def upright_posture_bonus(task: RobotTask, cfg: c.Upright) -> torch.Tensor:
    return (-task.robot.projected_gravity_b[:, 2] > cfg.threshold).to(task.ones.dtype)


def move_to_target_bonus(task: RobotTask, cfg: c.MoveToTarget) -> torch.Tensor:
    heading = heading_projection(task, cfg.target)
    return torch.where(heading > cfg.threshold, 1.0, heading / cfg.threshold)


def action_l2(task: RobotTask, cfg: c.ActionL2) -> torch.Tensor:
    return task.action.square().sum(dim=1)


def action_rate_l2(task: RobotTask, cfg: c.ActionRateL2) -> torch.Tensor:
    return (task.action - task.previous_action).square().sum(dim=1)


def power_consumption(task: RobotTask, cfg: c.Energy) -> torch.Tensor:
    r = task.robot
    return (task.action * r.joint_vel * r.gear_ratio_scaled).abs().sum(dim=1)


def joint_pos_limits_penalty_ratio(task: RobotTask, cfg: c.JointPosLimits) -> torch.Tensor:
    r = task.robot
    scaled = r.joint_pos_normalized().abs()
    violation = (scaled - cfg.threshold) / (1.0 - cfg.threshold) * r.gear_ratio_scaled
    return (violation * (scaled > cfg.threshold)).sum(dim=1)


class joint_torques_l2:  # noqa: N801
    """Squared actuator torques at the robot's joints, from jointactuatorfrc sensors."""

    def __init__(self, task: RobotTask, cfg: c.JointTorquesL2):
        self.torques = sensors.columns(task, [[sensors.joint_torque(j).name]
                                              for j in task.robot.joint_names])

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.JointTorquesL2) -> list[sensors.Sensor]:
        joints = sorted({int(model.actuator_trnid[a, 0]) for a in range(model.nu)})
        return [sensors.joint_torque(model.joint(j).name) for j in joints]

    def __call__(self) -> torch.Tensor:
        return self.torques().square().sum(dim=1)


class joint_acc_l2:  # noqa: N801
    """Squared joint accelerations, as the change of joint velocity over the env step."""

    def __init__(self, task: RobotTask, cfg: c.JointAccL2):
        self.task = task
        self.before = torch.zeros_like(task.robot.joint_vel)

    def pre_physics(self) -> None:
        self.before.copy_(self.task.robot.joint_vel)

    def __call__(self) -> torch.Tensor:
        acc = (self.task.robot.joint_vel - self.before) / self.task.step_dt
        return acc.square().sum(dim=1)


def flat_orientation_l2(task: RobotTask, cfg: c.FlatOrientationL2) -> torch.Tensor:
    return task.robot.projected_gravity_b[:, :2].square().sum(dim=1)


def lin_vel_z_l2(task: RobotTask, cfg: c.LinVelZL2) -> torch.Tensor:
    return task.robot.root_lin_vel_b[:, 2].square()


def ang_vel_xy_l2(task: RobotTask, cfg: c.AngVelXYL2) -> torch.Tensor:
    return task.robot.root_ang_vel_b[:, :2].square().sum(dim=1)

