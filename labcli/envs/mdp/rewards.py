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
    return (task.robot.up_z > cfg.threshold).to(task.ones.dtype)


def move_to_target_bonus(task: RobotTask, cfg: c.MoveToTarget) -> torch.Tensor:
    # Past the threshold the quotient is over 1: capped, it is 1 there.
    return (heading_projection(task, cfg.target) / cfg.threshold).clamp_max_(1.0)


def action_l2(task: RobotTask, cfg: c.ActionL2) -> torch.Tensor:
    return task.action.square().sum(dim=1)


def action_rate_l2(task: RobotTask, cfg: c.ActionRateL2) -> torch.Tensor:
    return (task.action - task.previous_action).square().sum(dim=1)


def power_consumption(task: RobotTask, cfg: c.Energy) -> torch.Tensor:
    r = task.robot
    return (task.action * r.joint_vel * r.gear_ratio_scaled).abs().sum(dim=1)


def joint_pos_limits_penalty_ratio(task: RobotTask, cfg: c.JointPosLimits) -> torch.Tensor:
    r = task.robot
    # Below the threshold the clamp makes it 0, as a mask would.
    past = (r.joint_pos_normalized().abs() - cfg.threshold).clamp_min_(0.0)
    return past.div_(1.0 - cfg.threshold).mul_(r.gear_ratio_scaled).sum(dim=1)


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


class track_lin_vel_xy_exp:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.TrackLinVelXYExp):
        self.command = task.command(cfg.command)
        self.inv_var = 1.0 / cfg.std**2

    def __call__(self) -> torch.Tensor:
        error = self.command.lin_vel_error().square()
        return torch.exp(error.sum(dim=1).mul_(-self.inv_var))


class track_ang_vel_z_exp:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.TrackAngVelZExp):
        self.command = task.command(cfg.command)
        self.inv_var = 1.0 / cfg.std**2

    def __call__(self) -> torch.Tensor:
        return torch.exp(self.command.yaw_rate_error().square().mul_(-self.inv_var))


class feet_air_time:  # noqa: N801
    """Air time counted in env steps: a foot in contact at the end of the step that was not at
    the end of the last one touched down in this step, after `air + step` s in the air."""

    def __init__(self, task: RobotTask, cfg: c.FeetAirTime):
        self.contacts = sensors.BodyContacts(task, cfg.bodies, cfg.threshold)
        self.command, self.cfg, self.dt = task.command(cfg.command), cfg, task.step_dt
        feet = len(self.contacts.bodies)
        self.air = task.ones.new_zeros(task.num_envs, feet)
        self.was_in_contact = torch.zeros(task.num_envs, feet, dtype=torch.bool,
                                          device=task.ones.device)

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.FeetAirTime) -> list[sensors.Sensor]:
        return sensors.BodyContacts.sensors(model, cfg.bodies)

    def __call__(self) -> torch.Tensor:
        touchdown = self.contacts() & ~self.was_in_contact
        reward = ((self.air + (self.dt - self.cfg.threshold_s)) * touchdown).sum(dim=1)
        moving = torch.linalg.vector_norm(self.command.command[:, :2], dim=1) > 0.1
        return reward * moving

    def after_step(self) -> None:
        contact = self.contacts()
        self.air.add_(self.dt).masked_fill_(contact, 0.0)
        self.was_in_contact.copy_(contact)

    def reset(self, mask: torch.Tensor) -> None:
        # As Isaac Lab's contact sensor after a reset: no air time, no contact yet.
        self.air.masked_fill_(mask[:, None], 0.0)
        self.was_in_contact.masked_fill_(mask[:, None], False)


class undesired_contacts:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.UndesiredContacts):
        self.contacts = sensors.BodyContacts(task, cfg.bodies, cfg.threshold)
        self.dtype = task.ones.dtype

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.UndesiredContacts) -> list[sensors.Sensor]:
        return sensors.BodyContacts.sensors(model, cfg.bodies)

    def __call__(self) -> torch.Tensor:
        return self.contacts().sum(dim=1).to(self.dtype)
