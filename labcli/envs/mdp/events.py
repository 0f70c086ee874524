"""Event terms: per-env random changes of the state, at reset (`reset(mask)`) or at random
intervals (`pre_physics()`), drawn from the env's generator so that seeded runs repeat, in
place so that they replay inside the CUDA-graphed step."""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import torch

from labcli.envs.mdp import config as c
from labcli.envs.mdp import math, names

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
        # The env's rng is read when drawing: the env hands the task its own after building it.
        self.task.rng.uniform_(self.sample)
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


class reset_joints_by_scale:  # noqa: N801
    """The default joint velocities are 0: scaled by any draw they stay 0, so only positions
    are drawn."""

    def __init__(self, task: RobotTask, cfg: c.ResetJointsByScale):
        self.robot = task.robot
        self.draw = Uniform(task, [cfg.position_range] * len(task.robot.joint_ids))
        self.zero = torch.zeros_like(task.robot.default_joint_pos)

    def reset(self, mask: torch.Tensor) -> None:
        r = self.robot
        pos = self.draw() * r.default_joint_pos
        pos = torch.minimum(torch.maximum(pos, r.joint_lower), r.joint_upper)
        r.write_joints(pos, self.zero, mask)


class reset_root_state_uniform:  # noqa: N801
    """Only what the ranges move is drawn and written: with Isaac Lab's empty ranges (ant,
    humanoid) the term leaves the default pose as the reset put it, at no cost per step."""

    def __init__(self, task: RobotTask, cfg: c.ResetRootUniform):
        self.robot, self.sim = task.robot, task.sim
        ranges = [cfg.pose_range.get(k, (0.0, 0.0)) for k in c.POSE_KEYS]
        ranges += [cfg.velocity_range.get(k, (0.0, 0.0)) for k in c.POSE_KEYS]
        self.draw = Uniform(task, ranges)
        self.moves = any(lo != 0.0 or hi != 0.0 for lo, hi in ranges)
        self.turns = any(lo != 0.0 or hi != 0.0 for lo, hi in ranges[3:6])

    def reset(self, mask: torch.Tensor) -> None:
        if not self.moves:
            return
        r = self.robot
        offset, velocity = self.draw().split(6, dim=1)
        m = mask[:, None]
        quat = (math.quat_mul(r.root_quat, math.quat_from_rpy(*offset[:, 3:].unbind(1)))
                if self.turns else r.root_quat)
        pose = torch.cat((r.root_pos + offset[:, :3], quat), dim=1)
        root_qpos = self.sim.qpos[:, r.root_qpos]
        torch.where(m, pose, root_qpos, out=root_qpos)
        # The free joint's angular velocity is in the root's frame.
        root_qvel = self.sim.qvel[:, r.root_qvel]
        torch.where(m, velocity, root_qvel, out=root_qvel)


class push_by_setting_velocity:  # noqa: N801
    carried = ("time_left",)

    def __init__(self, task: RobotTask, cfg: c.PushByVelocity):
        self.task, self.dt = task, task.step_dt
        self.interval = Uniform(task, [cfg.interval_s])
        self.push = Uniform(task, [cfg.velocity_range.get(k, (0.0, 0.0)) for k in c.POSE_KEYS])
        self.time_left = self.interval()[:, 0].clone()
        self.root_qvel = task.sim.qvel[:, task.robot.root_qvel]

    def pre_physics(self) -> None:
        self.time_left.sub_(self.dt)
        due = self.time_left <= 0.0
        # Most steps no push is due: on the CPU the draws and masked writes are skipped.
        with self.task.rng.only_for(due) as some:
            if some:
                qvel = self.root_qvel
                torch.where(due[:, None], qvel + self.push(), qvel, out=qvel)
                torch.where(due, self.interval()[:, 0], self.time_left, out=self.time_left)


class _ModelEvent:
    """Draws per-env values of an MjModel field for some of its rows (the geoms or bodies of
    the named bodies) and hands them to the sim: at start-up for all envs, or at every reset
    for the envs reset. `ranges`: one per value of a row (a scalar field's one, a vector's
    per component)."""

    field: ClassVar[str]
    carried = ("values",)

    def __init__(self, task: RobotTask, rows: list[int], ranges: list[tuple[float, float]],
                 mode: str):
        self.sim = task.sim
        self.values = task.sim.model_field(self.field)
        self.rows = torch.tensor(rows, dtype=torch.long, device=self.values.device)
        self.draw = Uniform(task, ranges * len(rows))
        self.everyone = torch.ones(task.num_envs, dtype=torch.bool, device=self.values.device)
        self.base = self.column().clone()
        if mode == "reset":
            self.reset = self.apply
        else:  # RobotTask runs it once, at the env's first reset
            self.startup = lambda: self.apply(self.everyone)

    def restored(self) -> None:
        self.sim.model_changed(self.field, self.everyone)

    def column(self) -> torch.Tensor:
        return self.values[:, self.rows]

    def apply(self, mask: torch.Tensor) -> None:
        current = self.column()
        new = self.new_values(self.draw().to(self.values.dtype).view(current.shape))
        self.write(torch.where(mask.view(-1, *[1] * (current.dim() - 1)), new, current))
        self.sim.model_changed(self.field, mask)

    def new_values(self, drawn: torch.Tensor) -> torch.Tensor:
        return drawn

    def write(self, values: torch.Tensor) -> None:
        self.values[:, self.rows] = values


def _bodies(task: RobotTask, patterns: list[str]) -> list[int]:
    """The named bodies, the world (the floor's body) left out."""
    return [b for b in names.resolve(task.model, "body", patterns) if b != 0]


def _geoms_of(task: RobotTask, bodies: list[str]) -> list[int]:
    ids = set(_bodies(task, bodies))
    return [g for g in range(task.model.ngeom) if int(task.model.geom_bodyid[g]) in ids]


class randomize_rigid_body_friction(_ModelEvent):  # noqa: N801
    field = "geom_friction"
    fields = ("geom_friction",)

    def __init__(self, task: RobotTask, cfg: c.RandomizeFriction):
        super().__init__(task, _geoms_of(task, cfg.bodies), [cfg.friction_range], cfg.mode)

    def column(self) -> torch.Tensor:
        return self.values[:, self.rows, 0]  # sliding friction

    def write(self, values: torch.Tensor) -> None:
        self.values[:, self.rows, 0] = values


class _AddedToModel(_ModelEvent):
    """The model's own value plus the draw."""

    def new_values(self, drawn: torch.Tensor) -> torch.Tensor:
        return self.base + drawn


class randomize_rigid_body_mass(_AddedToModel):  # noqa: N801
    field = "body_mass"
    fields = ("body_mass",)

    def __init__(self, task: RobotTask, cfg: c.RandomizeMass):
        super().__init__(task, _bodies(task, cfg.bodies), [cfg.mass_range], cfg.mode)


class randomize_rigid_body_com(_AddedToModel):  # noqa: N801
    field = "body_ipos"
    fields = ("body_ipos",)

    def __init__(self, task: RobotTask, cfg: c.RandomizeCom):
        axes = [cfg.com_range.get(axis, (0.0, 0.0)) for axis in ("x", "y", "z")]
        super().__init__(task, _bodies(task, cfg.bodies), axes, cfg.mode)
