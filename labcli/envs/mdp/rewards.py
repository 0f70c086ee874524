"""Reward terms, unweighted (the weight is the term's config): each a function of the task
returning `[num_envs]`, or a class made once per task. Names follow Isaac Lab's `mdp`."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

import mujoco
import torch

from labcli.envs.mdp import config as c
from labcli.envs.mdp import names, objects, sensors
from labcli.envs.mdp.feet import (
    FootContacts,
    FootSites,
    feet_sensors,
    paired_sites,
    site_names,
)
from labcli.envs.mdp.observations import distance_to_target, heading_projection
from labcli.envs.mdp.robot import Robot
from labcli.errors import LabError

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


def joint_vel_l2(task: RobotTask, cfg: c.JointVelL2) -> torch.Tensor:
    return task.robot.joint_vel.square().sum(dim=1)


class position_command_error:  # noqa: N801 - a term, named as Isaac Lab's
    def __init__(self, task: RobotTask, cfg: c.PositionCommandError):
        self.command = task.command(cfg.command)

    def __call__(self) -> torch.Tensor:
        return self.command.position_error()


class position_command_error_tanh:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.PositionCommandErrorTanh):
        self.command, self.inv_std = task.command(cfg.command), 1.0 / cfg.std

    def __call__(self) -> torch.Tensor:
        return _tanh_kernel(self.command.position_error(), self.inv_std)


class orientation_command_error:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.OrientationCommandError):
        self.command = task.command(cfg.command)

    def __call__(self) -> torch.Tensor:
        return self.command.orientation_error()


class object_ee_distance:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.ObjectReach):
        self.reach, self.inv_std = objects.site_to_object(task, cfg.site, cfg.object), 1.0 / cfg.std

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.ObjectReach) -> list[sensors.Sensor]:
        return objects.site_sensors(cfg.site)

    def __call__(self) -> torch.Tensor:
        return _tanh_kernel(torch.linalg.vector_norm(self.reach(), dim=1), self.inv_std)


class object_grasped:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.ObjectGrasped):
        self.held = objects.grasp(task, cfg.object, cfg.fingers, cfg.squeeze)

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.ObjectGrasped) -> list[sensors.Sensor]:
        return objects.grasp_sensors(cfg.object, cfg.fingers)

    def __call__(self) -> torch.Tensor:
        return self.held().float()


class _Lifted:
    """Where the object is above the term's minimal height, and held if it asks."""

    def __init__(self, task: RobotTask, cfg: c.ObjectLifted | c.ObjectGoalDistance):
        self.object, self.cfg = objects.free_body(task, cfg.object), cfg
        self.held = None if cfg.held_by is None else objects.grasp(task, cfg.object,
                                                                    cfg.held_by, cfg.squeeze)

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.HeldObjectTerm) -> list[sensors.Sensor]:
        return [] if cfg.held_by is None else objects.grasp_sensors(cfg.object, cfg.held_by)

    def lifted(self) -> torch.Tensor | None:
        """Where it counts, `[n]` (bool); None: everywhere."""
        lifted = (None if self.cfg.minimal_height is None
                  else self.object.height > self.cfg.minimal_height)
        if self.held is None:
            return lifted
        return self.held() if lifted is None else lifted.logical_and_(self.held())


class object_is_lifted(_Lifted):  # noqa: N801
    def __call__(self) -> torch.Tensor:
        lifted = self.lifted()
        assert lifted is not None  # ObjectLifted's minimal height is a number
        return lifted.to(self.object.height.dtype)


class object_goal_distance(_Lifted):  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.ObjectGoalDistance):
        super().__init__(task, cfg)
        self.command, self.inv_std = task.command(cfg.command), 1.0 / cfg.std
        self.kernel = _tanh_kernel if cfg.kernel == "tanh" else _gaussian_kernel

    def __call__(self) -> torch.Tensor:
        distance = torch.linalg.vector_norm(self.command.target_world() - self.object.pos, dim=1)
        near, lifted = self.kernel(distance, self.inv_std), self.lifted()
        return near if lifted is None else near.mul_(lifted)


def _tanh_kernel(distance: torch.Tensor, inv_std: float) -> torch.Tensor:
    return 1.0 - torch.tanh(distance * inv_std)


def _gaussian_kernel(distance: torch.Tensor, inv_std: float) -> torch.Tensor:
    return torch.exp(-(distance * inv_std).square())


class staged_position_reward:  # noqa: N801 - a term, named as mjlab's
    def __init__(self, task: RobotTask, cfg: c.ObjectStagedReach):
        self.object, self.command = objects.free_body(task, cfg.object), task.command(cfg.command)
        self.reach = objects.site_to_object(task, cfg.site, cfg.object)
        self.inv_reach, self.inv_bring = 1.0 / cfg.reaching_std, 1.0 / cfg.bringing_std

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.ObjectStagedReach) -> list[sensors.Sensor]:
        return objects.site_sensors(cfg.site)

    def __call__(self) -> torch.Tensor:
        reach = _gaussian_kernel(torch.linalg.vector_norm(self.reach(), dim=1), self.inv_reach)
        bring = _gaussian_kernel(torch.linalg.vector_norm(
            self.command.target_world() - self.object.pos, dim=1), self.inv_bring)
        return bring.add_(1.0).mul_(reach)


def joint_vel_hinge(task: RobotTask, cfg: c.JointVelHinge) -> torch.Tensor:
    return (task.robot.joint_vel.abs() - cfg.max_vel).clamp_min_(0.0).square_().sum(dim=1)


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
    if cfg.reference == "gravity":
        return task.robot.projected_gravity_b[:, :2].square().sum(dim=1)
    return _terrain_normal_b(task, cfg.span)[:, :2].square().sum(dim=1)


def _terrain_normal_b(task: RobotTask, span: float) -> torch.Tensor:
    """The terrain's normal under the root, in the root's frame `[n, 3]` (Rᵀn, as summed
    products: a matrix product may run in TF32 on a GPU); a term that reads it needs
    env.terrain."""
    if task.terrain is None:
        raise LabError("a reward measures uprightness against the terrain, and the task has "
                       "none", "give env.terrain, or set the term's reference to gravity")
    r = task.robot
    return task.robot.per_state(("terrain_normal_b", span), lambda: (
        task.terrain.normal(r.root_xy, span)[:, :, None] * r.rotation).sum(dim=1))


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

    carried = ("air", "was_in_contact")

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


# mjlab's velocity task, as its G1 uses it ----------------------------------------------------
def command_speed(task: RobotTask, command) -> torch.Tensor:
    """|command lin xy| + |command yaw rate| `[n]`, once per state: how much a velocity command
    asks, by which mjlab's terms choose a posture's tolerance and gate the foot terms."""
    return task.robot.per_state(("command_speed", command), lambda: (
        torch.linalg.vector_norm(command.command[:, :2], dim=1).add_(command.command[:, 2].abs())))


def command_active(task: RobotTask, command, threshold: float) -> torch.Tensor:
    """1 where the command asks more than `threshold` (`command_speed`), else 0, `[n]`."""
    return task.robot.per_state(("command_active", command, threshold), lambda: (
        (command_speed(task, command) > threshold).to(task.ones.dtype)))


def _body(model: mujoco.MjModel, body: str | None) -> str:
    """`body`, checked; None: the root (the first body with a free joint)."""
    if body is None:
        root = Robot._root_joint(model, None)
        if root is None:
            raise LabError(f"a term of the root body needs a floating base (a free joint), and "
                           f"model '{names.model_name(model)}' has none",
                           "name its body (body: NAME)")
        return names.all_names(model, "body")[int(model.jnt_bodyid[root])]
    names.resolve_one(model, "body", body)
    return body


class track_linear_velocity:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.TrackLinearVelocity):
        self.command = task.command(cfg.command)
        self.vel_z = task.robot.root_lin_vel_b[:, 2]
        self.inv_var = 1.0 / cfg.std**2

    def __call__(self) -> torch.Tensor:
        error = self.command.lin_vel_error().square().sum(dim=1).add_(self.vel_z.square())
        return torch.exp(error.mul_(-self.inv_var))


class track_angular_velocity:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.TrackAngularVelocity):
        self.command = task.command(cfg.command)
        self.ang_vel_xy = task.robot.root_ang_vel_b[:, :2]
        self.inv_var = 1.0 / cfg.std**2

    def __call__(self) -> torch.Tensor:
        error = self.ang_vel_xy.square().sum(dim=1).add_(self.command.yaw_rate_error().square())
        return torch.exp(error.mul_(-self.inv_var))


def _axes(body: str) -> list[sensors.Sensor]:
    return [sensors.frame("framexaxis", "xbody", body), sensors.frame("frameyaxis", "xbody", body)]


class upright:  # noqa: N801
    """Gravity's direction in a body's frame is -(R20, R21, R22) (R: the body's rotation): its
    xy are minus the world z of the body's x and y axes, read from framexaxis and frameyaxis
    sensors (the root's from the robot's own)."""

    def __init__(self, task: RobotTask, cfg: c.UprightExp):
        self.inv_var = 1.0 / cfg.std**2
        if cfg.reference == "terrain":
            if cfg.body is not None:
                raise LabError("upright against the terrain is measured at the root",
                               "leave the term's body out (null), or set reference gravity")
            self.gravity_xy = lambda: _terrain_normal_b(task, cfg.span)[:, :2]
        elif cfg.body is None:
            self.gravity_xy = lambda: task.robot.projected_gravity_b[:, :2]
        else:
            axes = sensors.columns(task, [[s.name] for s in _axes(cfg.body)])
            self.gravity_xy = lambda: axes().view(-1, 2, 3)[:, :, 2]

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.UprightExp) -> list[sensors.Sensor]:
        return [] if cfg.body is None else _axes(_body(model, cfg.body))

    def __call__(self) -> torch.Tensor:
        return torch.exp(self.gravity_xy().square().sum(dim=1).mul_(-self.inv_var))


def _per_joint(joints: list[str], stds: dict[str, float], field: str) -> list[float]:
    """Each joint's std, by the first pattern matching its whole name."""
    values = []
    for joint in joints:
        std = next((v for p, v in stds.items() if re.fullmatch(p, joint)), None)
        if std is None:
            raise LabError(f"joint '{joint}' matches none of {field}'s patterns "
                           f"({', '.join(repr(p) for p in stds)})",
                           f"give {field} a pattern for it ('.*' last matches every joint)")
        values.append(std)
    return values


class variable_posture:  # noqa: N801
    """mean(((q - q0) / std)^2) as sum((q - q0)^2 w), w = 1 / (joints x std^2) per regime,
    chosen per env by where: no host sync, no branch on the command."""

    def __init__(self, task: RobotTask, cfg: c.VariablePosture):
        r = self.robot = task.robot
        self.task, self.cfg, self.command = task, cfg, task.command(cfg.command)
        k = len(r.joint_names)

        def weights(field: str) -> torch.Tensor:
            stds = _per_joint(r.joint_names, getattr(cfg, field), field)
            return task.tiled([1.0 / (k * std**2) for std in stds])

        self.standing, self.walking, self.running = (
            weights("std_standing"), weights("std_walking"), weights("std_running"))
        self._w = torch.empty_like(self.standing)
        self._error = torch.empty_like(self.standing)

    def __call__(self) -> torch.Tensor:
        cfg, r, w = self.cfg, self.robot, self._w
        speed = command_speed(self.task, self.command)[:, None]
        torch.where(speed >= cfg.running_threshold, self.running, self.walking, out=w)
        torch.where(speed < cfg.walking_threshold, self.standing, w, out=w)
        error = torch.sub(r.joint_pos, r.default_joint_pos, out=self._error)
        return torch.exp(error.square_().mul_(w).sum(dim=1).neg_())


class body_angular_velocity_penalty:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.BodyAngVelXYL2):
        self.ang_vel = sensors.columns(task, [[sensors.frame("frameangvel", "xbody",
                                                             cfg.body).name]])

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.BodyAngVelXYL2) -> list[sensors.Sensor]:
        return [sensors.frame("frameangvel", "xbody", _body(model, cfg.body))]

    def __call__(self) -> torch.Tensor:
        return self.ang_vel()[:, :2].square().sum(dim=1)


class angular_momentum_penalty:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.AngularMomentumL2):
        self.momentum = sensors.columns(task, [[sensors.subtree_angmom(
            _body(task.model, None)).name]])

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.AngularMomentumL2) -> list[sensors.Sensor]:
        return [sensors.subtree_angmom(_body(model, None))]

    def __call__(self) -> torch.Tensor:
        return self.momentum().square().sum(dim=1)


class joint_pos_limits:  # noqa: N801
    """Soft limits as mjlab's: the middle of the range -/+ half of it times the factor; an
    unlimited joint's are -/+ infinity."""

    def __init__(self, task: RobotTask, cfg: c.SoftJointPosLimits):
        model, ids = task.model, task.robot.joint_ids
        inf = float("inf")
        lower, upper = [], []
        for j in ids:
            low, high = (float(v) for v in model.jnt_range[j])
            middle, half = (low + high) / 2, (high - low) / 2 * cfg.soft_factor
            limited = bool(model.jnt_limited[j])
            lower.append(middle - half if limited else -inf)
            upper.append(middle + half if limited else inf)
        self.robot, self.lower, self.upper = task.robot, task.tiled(lower), task.tiled(upper)
        self._below = torch.empty_like(self.lower)
        self._above = torch.empty_like(self.lower)

    def __call__(self) -> torch.Tensor:
        q = self.robot.joint_pos
        below = torch.sub(self.lower, q, out=self._below).clamp_min_(0.0)
        above = torch.sub(q, self.upper, out=self._above).clamp_min_(0.0)
        return below.add_(above).sum(dim=1)


class feet_clearance:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.FeetClearance):
        self.task, self.cfg, self.command = task, cfg, task.command(cfg.command)
        self.sites = FootSites.of(task, site_names(task.model, cfg.sites))

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.FeetClearance) -> list[sensors.Sensor]:
        return FootSites.sensors(model, site_names(model, cfg.sites))

    def __call__(self) -> torch.Tensor:
        cost = (self.sites.heights() - self.cfg.target_height).abs_().mul_(self.sites.speed_xy())
        return cost.sum(dim=1).mul_(command_active(self.task, self.command,
                                                   self.cfg.command_threshold))


def _feet_sensors(model: mujoco.MjModel, cfg: c.FeetSwingHeight | c.FeetSlip
                  ) -> list[sensors.Sensor]:
    return feet_sensors(model, cfg.bodies, cfg.sites)


class _FootTerm:
    """The feet's contacts and, with `sites`, one site on each foot in the same order."""

    def __init__(self, task: RobotTask, cfg: c.FootContactTerm):
        self.task, self.cfg, self.command = task, cfg, task.command(cfg.command)
        self.contacts = FootContacts.of(task, cfg.bodies)
        sites = getattr(cfg, "sites", None)
        if sites is not None:
            self.sites = FootSites.of(task, paired_sites(task.model, self.contacts.bodies, sites))

    def active(self) -> torch.Tensor:
        return command_active(self.task, self.command, self.cfg.command_threshold)


class feet_swing_height(_FootTerm):  # noqa: N801
    """Each foot's peak height in the air, at the ends of steps: the peak so far and this
    step's where it is in the air (`peak_now`, once per state), kept by `after_step` and
    cleared where the foot lands and at reset."""

    carried = ("peak",)

    def __init__(self, task: RobotTask, cfg: c.FeetSwingHeight):
        super().__init__(task, cfg)
        self.peak = task.ones.new_zeros(task.num_envs, len(self.contacts.bodies))
        self.inv_target = 1.0 / cfg.target_height

    sensors = staticmethod(_feet_sensors)

    def peak_now(self) -> torch.Tensor:
        return self.task.robot.per_state(("feet_swing_peak", self), lambda: torch.where(
            self.contacts.touching(), self.peak, torch.maximum(self.peak, self.sites.heights())))

    def __call__(self) -> torch.Tensor:
        error = (self.peak_now() * self.inv_target - 1.0).square_()
        cost = error.mul_(self.contacts.first_contact()).sum(dim=1)
        return cost.mul_(self.active())

    def after_step(self) -> None:
        self.peak.copy_(self.peak_now()).masked_fill_(self.contacts.first_contact(), 0.0)

    def reset(self, mask: torch.Tensor) -> None:
        self.peak.masked_fill_(mask[:, None], 0.0)


class feet_slip(_FootTerm):  # noqa: N801
    sensors = staticmethod(_feet_sensors)

    def __call__(self) -> torch.Tensor:
        slip = self.sites.speed_xy().square().mul_(self.contacts.touching())
        return slip.sum(dim=1).mul_(self.active())


class soft_landing(_FootTerm):  # noqa: N801
    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.SoftLanding) -> list[sensors.Sensor]:
        return FootContacts.sensors(model, cfg.bodies)

    def __call__(self) -> torch.Tensor:
        impact = self.contacts.force_norm() * self.contacts.first_contact()
        return impact.sum(dim=1).mul_(self.active())


class self_collision_cost:  # noqa: N801
    """The self-contacts' forces, largest first, counted over the threshold."""

    def __init__(self, task: RobotTask, cfg: c.SelfCollisions):
        sensor = sensors.self_contacts(_body(task.model, cfg.body), cfg.max_contacts)
        self.forces = sensors.columns(task, [[sensor.name]])
        self.shape, self.threshold = (task.num_envs, cfg.max_contacts, 3), cfg.force_threshold
        self.dtype = task.ones.dtype

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.SelfCollisions) -> list[sensors.Sensor]:
        return [sensors.self_contacts(_body(model, cfg.body), cfg.max_contacts)]

    def __call__(self) -> torch.Tensor:
        force = torch.linalg.vector_norm(self.forces().view(self.shape), dim=2)
        return (force > self.threshold).sum(dim=1).to(self.dtype)
