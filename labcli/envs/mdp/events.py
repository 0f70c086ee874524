"""Event terms: per-env random changes of the state, at reset (`reset(mask)`) or at random
intervals (`pre_physics()`), drawn from the env's generator so that seeded runs repeat, in
place so that they replay inside the CUDA-graphed step."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from labcli.envs.mdp import config as c
from labcli.envs.mdp import math

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask


class Uniform:
    """Draws `[num_envs, k]` uniform samples, one range per column, into a buffer made once."""

    def __init__(self, task: RobotTask, ranges: list[tuple[float, float]]):
        low = task.constant([r[0] for r in ranges])
        self.low = low.expand(task.num_envs, len(ranges)).contiguous()
        self.width = (task.constant([r[1] for r in ranges]) - low).expand_as(self.low).contiguous()
        self.sample = torch.empty_like(self.low)
        self.task = task

    def __call__(self) -> torch.Tensor:
        # The generator is read when drawing: the env hands the task its own after building it.
        torch.rand(self.sample.shape, generator=self.task.generator, out=self.sample)
        # Not addcmul: its fused multiply-add rounds differently from one backend to the other.
        return self.sample.mul_(self.width).add_(self.low)


class reset_joints_by_offset:  # noqa: N801 - a term, named as Isaac Lab's
    def __init__(self, task: RobotTask, cfg: c.ResetJointsByOffset):
        self.robot = task.robot
        k = len(task.robot.joint_ids)
        self.draw = Uniform(task, [cfg.position_range] * k + [cfg.velocity_range] * k)

    def reset(self, mask: torch.Tensor) -> None:
        r = self.robot
        pos, vel = self.draw().split(len(r.joint_ids), dim=1)
        pos = torch.minimum(torch.maximum(pos + r.default_joint_pos, r.joint_lower), r.joint_upper)
        r.write_joints(pos, vel, mask)


class reset_root_state_uniform:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.ResetRootUniform):
        self.robot, self.sim = task.robot, task.sim
        ranges = [cfg.pose_range.get(k, (0.0, 0.0)) for k in c.POSE_KEYS]
        ranges += [cfg.velocity_range.get(k, (0.0, 0.0)) for k in c.POSE_KEYS]
        self.draw = Uniform(task, ranges)

    def reset(self, mask: torch.Tensor) -> None:
        r = self.robot
        offset, velocity = self.draw().split(6, dim=1)
        m = mask[:, None]
        pos = r.root_pos + offset[:, :3]
        quat = math.quat_mul(r.root_quat, math.quat_from_rpy(*offset[:, 3:].unbind(1)))
        torch.where(m, torch.cat((pos, quat), dim=1), self.sim.qpos[:, r.root_qpos],
                    out=self.sim.qpos[:, r.root_qpos])
        # The free joint's angular velocity is in the root's frame.
        torch.where(m, velocity, self.sim.qvel[:, r.root_qvel], out=self.sim.qvel[:, r.root_qvel])


class push_by_setting_velocity:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.PushByVelocity):
        self.sim, self.robot, self.dt = task.sim, task.robot, task.step_dt
        self.interval = Uniform(task, [cfg.interval_s])
        self.push = Uniform(task, [cfg.velocity_range.get(k, (0.0, 0.0)) for k in c.POSE_KEYS])
        self.time_left = self.interval()[:, 0].clone()

    def pre_physics(self) -> None:
        self.time_left.sub_(self.dt)
        due = self.time_left <= 0.0
        qvel = self.sim.qvel[:, self.robot.root_qvel]
        torch.where(due[:, None], qvel + self.push(), qvel, out=qvel)
        torch.where(due, self.interval()[:, 0], self.time_left, out=self.time_left)
