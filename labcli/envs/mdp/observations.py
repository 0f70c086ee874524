"""Observation terms: each a function of the task returning `[num_envs, k]`, or a class made
once per task and called each step. Names follow Isaac Lab's `mdp` module."""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import torch

from labcli.envs.mdp import config as c
from labcli.envs.mdp import events, math, names, objects, sensors
from labcli.envs.mdp.feet import FootContacts, FootSites, feet_sensors, paired_sites
from labcli.errors import LabError

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask


def base_height(task: RobotTask, cfg: c.BaseHeight) -> torch.Tensor:
    return task.base_height()[:, None]


def base_lin_vel(task: RobotTask, cfg: c.BaseLinVel) -> torch.Tensor:
    return task.robot.root_lin_vel_b


def base_ang_vel(task: RobotTask, cfg: c.BaseAngVel) -> torch.Tensor:
    return task.robot.root_ang_vel_b


class projected_gravity:  # noqa: N801 - a term, named as Isaac Lab's
    """Gravity in the root's frame, or in the frame of a site fixed to the root (an IMU's,
    turned by the site's own rotation in the root), then into each env's IMU mounting, drawn
    at its episodes' start (only where a range is set). Computed from the root's state, not
    read from sensors, which hold the state before a step's last physics step."""

    carried = ("frame",)

    def __init__(self, task: RobotTask, cfg: c.ProjectedGravity):
        self.robot = task.robot
        site = [1.0, 0.0, 0.0, 0.0]
        if cfg.site is not None:
            model = task.model
            sid = names.resolve_one(model, "site", cfg.site)
            if model.site_bodyid[sid] != task.robot.root_body:
                root = names.all_names(model, "body")[task.robot.root_body]
                raise LabError(f"IMU site '{cfg.site}' is not on the root body '{root}'",
                               "name a site of the root body (or none: the root's frame)")
            site = model.site_quat[sid].tolist()
        ranges = [cfg.mounting_range.get(k, (0.0, 0.0)) for k in c.MOUNTING_KEYS]
        self.draw = events.Uniform(task, ranges) if any(lo or hi for lo, hi in ranges) else None
        self.site = task.tiled(site)
        # Per env, the IMU's frame in the root's: the site's rotation, then the mounting's.
        self.frame = self.site.clone()
        self.turned = cfg.site is not None or self.draw is not None

    def reset(self, mask: torch.Tensor) -> None:
        if self.draw is not None:
            frame = math.quat_mul(self.site, math.quat_from_rpy(*self.draw().unbind(1)))
            torch.where(mask[:, None], frame, self.frame, out=self.frame)

    def __call__(self) -> torch.Tensor:
        gravity = self.robot.projected_gravity_b
        return math.quat_apply_inverse(self.frame, gravity) if self.turned else gravity


def base_yaw_roll(task: RobotTask, cfg: c.BaseYawRoll) -> torch.Tensor:
    return torch.stack((task.robot.yaw, task.robot.roll), dim=1)


def base_up_proj(task: RobotTask, cfg: c.UpProj) -> torch.Tensor:
    return task.robot.up_z[:, None]


def to_target(task: RobotTask, target: tuple[float, float, float]) -> torch.Tensor:
    """The horizontal vector (x, y) from the root to `target`, `[n, 2]`. This and the values
    below are computed once per state: observations, rewards and success share them."""
    return task.robot.per_state(("to_target", target), lambda: (
        torch.sub(task.tiled(target[:2]), task.robot.root_xy)))


def distance_to_target(task: RobotTask, target: tuple[float, float, float]) -> torch.Tensor:
    return task.robot.per_state(("distance_to_target", target), lambda: (
        torch.linalg.vector_norm(to_target(task, target), dim=1)))


def direction_to_target(task: RobotTask, target: tuple[float, float, float]) -> torch.Tensor:
    """The horizontal unit vector (x, y) from the root toward `target`, `[n, 2]`."""
    return task.robot.per_state(("direction_to_target", target), lambda: (
        to_target(task, target) / distance_to_target(task, target).clamp_min(1e-12)[:, None]))


def heading_projection(task: RobotTask, target: tuple[float, float, float]) -> torch.Tensor:
    """The root's forward (x) axis projected on the horizontal direction to `target`, `[n]`."""
    return task.robot.per_state(("heading_projection", target), lambda: (
        (task.robot.forward_xy * direction_to_target(task, target)).sum(dim=1)))


def base_heading_proj(task: RobotTask, cfg: c.HeadingProj) -> torch.Tensor:
    return heading_projection(task, cfg.target)[:, None]


def base_angle_to_target(task: RobotTask, cfg: c.AngleToTarget) -> torch.Tensor:
    x, y = to_target(task, cfg.target).unbind(1)
    angle = torch.atan2(y, x) - task.robot.yaw
    return math.wrap_to_pi(angle)[:, None]


def joint_pos_rel(task: RobotTask, cfg: c.JointPos) -> torch.Tensor:
    relative = task.robot.joint_pos - task.robot.default_joint_pos
    return relative.add_(task.robot.encoder_bias) if cfg.biased else relative


def joint_pos_limit_normalized(task: RobotTask, cfg: c.JointPosNormalized) -> torch.Tensor:
    return task.robot.joint_pos_normalized()


def joint_vel_rel(task: RobotTask, cfg: c.JointVel) -> torch.Tensor:
    return task.robot.joint_vel


class generated_commands:  # noqa: N801 - a term, named as Isaac Lab's
    def __init__(self, task: RobotTask, cfg: c.GeneratedCommands):
        self.command = task.command(cfg.command)
        self.names = getattr(self.command, "names", None)
        self.units = getattr(self.command, "units", None)

    def __call__(self) -> torch.Tensor:
        return self.command()


def last_action(task: RobotTask, cfg: c.LastAction) -> torch.Tensor:
    return task.action


class object_position_in_robot_root_frame:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.ObjectPosition):
        self.object = objects.free_body(task, cfg.object)
        self.base = objects.fixed_frame(task, cfg.base_body)

    def __call__(self) -> torch.Tensor:
        return self.base.local(self.object.pos)


class object_from_site:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.ObjectFromSite):
        self.reach = objects.site_to_object(task, cfg.site, cfg.object)
        self.base = objects.fixed_frame(task, cfg.base_body)

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.ObjectFromSite) -> list[sensors.Sensor]:
        return objects.site_sensors(cfg.site)

    def __call__(self) -> torch.Tensor:
        return math.quat_apply_inverse(self.base.quat, self.reach())


class object_to_target:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.ObjectToTarget):
        self.object, self.command = objects.free_body(task, cfg.object), task.command(cfg.command)

    def __call__(self) -> torch.Tensor:
        return self.command()[:, :3] - self.command.base.local(self.object.pos)


class height_scan:  # noqa: N801 - a term, named as Isaac Lab's
    """The base's height above the terrain (`task.terrain`) under each point of the grid, turned
    with the base's yaw, minus the offset."""

    def __init__(self, task: RobotTask, cfg: c.HeightScan):
        if task.terrain is None:
            raise LabError("observation height_scan reads the terrain, and the task has none",
                           "give env.terrain, or leave height_scan out (null)")
        self.robot, self.terrain, self.offset = task.robot, task.terrain, cfg.offset
        xs = _ticks(cfg.length, cfg.resolution)
        ys = _ticks(cfg.width, cfg.resolution)
        self.names = [f"{x:+.2f},{y:+.2f}" for y in ys for x in xs]
        grid = [(x, y) for y in ys for x in xs]
        self.px, self.py = task.constant([p[0] for p in grid]), task.constant([p[1] for p in grid])

    def __call__(self) -> torch.Tensor:
        r = self.robot
        cos, sin = torch.cos(r.yaw)[:, None], torch.sin(r.yaw)[:, None]
        x = r.root_xy[:, :1] + cos * self.px - sin * self.py
        y = r.root_xy[:, 1:] + sin * self.px + cos * self.py
        below = self.terrain.heights(torch.stack((x, y), dim=-1))
        return r.root_height[:, None] - below - self.offset


def _ticks(length: float, step: float) -> list[float]:
    """Points every `step` across `length`, centred on 0 (Isaac Lab's grid pattern)."""
    count = int(round(length / step, 9)) + 1
    return [-length / 2 + i * step for i in range(count)]


class body_incoming_wrench:  # noqa: N801 - a term, named as Isaac Lab's
    """Force and torque sensors at each named body's frame, 6 values per body."""

    def __init__(self, task: RobotTask, cfg: c.BodyWrench):
        self.bodies = sensors.body_names(task.model, cfg.bodies)
        self.data = sensors.columns(task, [sensors.wrench_names(b) for b in self.bodies])
        self.names = [f"{b}.{axis}" for b in self.bodies
                      for axis in ("fx", "fy", "fz", "tx", "ty", "tz")]
        self.units = ["N, body frame"] * 3 + ["N m, body frame"] * 3
        self.units *= len(self.bodies)

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.BodyWrench) -> list[sensors.Sensor]:
        return [s for body in sensors.body_names(model, cfg.bodies) for s in sensors.wrench(body)]

    def __call__(self) -> torch.Tensor:
        return self.data()


class contact_forces:  # noqa: N801
    """Contact sensors on each named body, the net force (3 values) per body."""

    def __init__(self, task: RobotTask, cfg: c.ContactForces):
        self.bodies = sensors.body_names(task.model, cfg.bodies)
        self.data = sensors.columns(task, [sensors.contact_names(b) for b in self.bodies])
        self.names = [f"{b}.{axis}" for b in self.bodies for axis in ("fx", "fy", "fz")]

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.ContactForces) -> list[sensors.Sensor]:
        return [sensors.contact(body) for body in sensors.body_names(model, cfg.bodies)]

    def __call__(self) -> torch.Tensor:
        return self.data()


class _feet:
    """The feet's contacts with the terrain (shared with the foot rewards), one column per
    foot, named by its body."""

    def __init__(self, task: RobotTask, cfg: c.FootObs):
        self.contacts = FootContacts.of(task, cfg.bodies)
        self.names = list(self.contacts.bodies)
        self.dtype = task.ones.dtype

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.FootObs) -> list[sensors.Sensor]:
        return FootContacts.sensors(model, cfg.bodies)


class foot_height(_feet):  # noqa: N801 - a term, named as mjlab's
    def __init__(self, task: RobotTask, cfg: c.FootHeight):
        super().__init__(task, cfg)
        self.sites = FootSites.of(task, paired_sites(task.model, self.contacts.bodies, cfg.sites))

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.FootHeight) -> list[sensors.Sensor]:
        return feet_sensors(model, cfg.bodies, cfg.sites)

    def __call__(self) -> torch.Tensor:
        return self.sites.heights()


class foot_air_time(_feet):  # noqa: N801
    def __call__(self) -> torch.Tensor:
        return self.contacts.air_time_kept()


class foot_contact(_feet):  # noqa: N801
    def __call__(self) -> torch.Tensor:
        return self.contacts.touching().to(self.dtype)


class foot_contact_forces(_feet):  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.FootContactForces):
        super().__init__(task, cfg)
        self.names = [f"{b}.{axis}" for b in self.contacts.bodies for axis in ("fx", "fy", "fz")]

    def __call__(self) -> torch.Tensor:
        force = self.contacts.force().flatten(1)
        return torch.sign(force).mul_(torch.log1p(force.abs()))
