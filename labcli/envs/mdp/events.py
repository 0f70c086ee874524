"""Event terms: per-env random changes of the state, at reset (`reset(mask)`) or at random
intervals (`pre_physics()`), drawn from the env's generator so that seeded runs repeat, in
place so that they replay inside the CUDA-graphed step."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import mujoco
import torch

from labcli.envs.mdp import config as c
from labcli.envs.mdp import math, names, objects
from labcli.errors import LabError

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
        self.sim = task.sim
        # The free joint it moves: the robot's root, or the object's.
        if cfg.body is None:
            r = task.robot
            self.pos, self.quat, self.qpos, self.qvel = (r.root_pos, r.root_quat, r.root_qpos,
                                                         r.root_qvel)
        else:
            body = objects.free_body(task, cfg.body)
            self.pos, self.quat, self.qpos, self.qvel = body.pos, body.quat, body.qpos, body.qvel
        ranges = pose_ranges(cfg.pose_range) + pose_ranges(cfg.velocity_range)
        self.draw = Uniform(task, ranges)
        self.moves = any(lo != 0.0 or hi != 0.0 for lo, hi in ranges)
        self.turns = turns(ranges)

    def reset(self, mask: torch.Tensor) -> None:
        if not self.moves:
            return
        offset, velocity = self.draw().split(6, dim=1)
        m = mask[:, None]
        pose = offset_pose(self.pos, self.quat, offset, self.turns)
        root_qpos = self.sim.qpos[:, self.qpos]
        torch.where(m, pose, root_qpos, out=root_qpos)
        # The free joint's angular velocity is in the root's frame.
        root_qvel = self.sim.qvel[:, self.qvel]
        torch.where(m, velocity, root_qvel, out=root_qvel)


def pose_ranges(ranges: dict[str, tuple[float, float]]) -> list[tuple[float, float]]:
    """`ranges` by POSE_KEYS in their order, those left out (0, 0)."""
    return [ranges.get(k, (0.0, 0.0)) for k in c.POSE_KEYS]


def turns(ranges: list[tuple[float, float]]) -> bool:
    """Whether pose offsets drawn from `ranges` (POSE_KEYS' order) turn the body."""
    return any(lo != 0.0 or hi != 0.0 for lo, hi in ranges[3:6])


def offset_pose(pos: torch.Tensor, quat: torch.Tensor, offset: torch.Tensor,
                turns: bool) -> torch.Tensor:
    """A free joint's qpos `[n, 7]`: `pos` moved by the offset's x, y, z and `quat` turned by
    its roll, pitch, yaw (where `turns`), `offset` `[n, 6]` in POSE_KEYS' order."""
    if turns:
        quat = math.quat_mul(quat, math.quat_from_rpy(*offset[:, 3:6].unbind(1)))
    return torch.cat((pos + offset[:, :3], quat), dim=1)


class push_by_setting_velocity:  # noqa: N801
    carried = ("time_left",)

    def __init__(self, task: RobotTask, cfg: c.PushByVelocity):
        self.task, self.dt = task, task.step_dt
        self.interval = Uniform(task, [cfg.interval_s])
        self.push = Uniform(task, pose_ranges(cfg.velocity_range))
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
    fields: ClassVar[tuple[str, ...]]  # every field it writes (the sim makes them per env)
    # Its rows' values, not the whole field: a terrain's thousands of geoms made a G1's
    # per-env friction 82 MB of every saved state.
    carried = ("drawn",)
    # What a lab before that carried: the whole fields, by their attributes' names.
    saved_fields: ClassVar[tuple[str, ...]] = ("values",)
    # How a draw becomes the value (Isaac Lab's operations): "abs" the draw itself, "add" the
    # model's own value plus it, "scale" the model's own value times it.
    operation = "abs"

    def __init__(self, task: RobotTask, rows: list[int], ranges: list[tuple[float, float]],
                 mode: str):
        self.sim = task.sim
        self.values = task.sim.model_field(self.field)
        self.rows = torch.tensor(rows, dtype=torch.long, device=self.values.device)
        self.base = self.column().clone()
        self.drawn = self.base.clone()
        self.draw = Uniform(task, ranges * self.base.shape[1])  # per row its ranges
        self.everyone = torch.ones(task.num_envs, dtype=torch.bool, device=self.values.device)
        if mode == "reset":
            self.reset = self.apply
        else:  # RobotTask runs it once, at the env's first reset
            self.startup = lambda: self.apply(self.everyone)

    def restored(self) -> None:
        self.write(self.drawn)
        for field in self.fields:
            self.sim.model_changed(field, self.everyone)

    def upgraded_state(self, owner: str, saved: dict[str, Any]) -> dict[str, Any]:
        """A state saved when the term carried its whole fields (`values`; an actuator's gains
        `bias` too): its rows' values taken from them."""
        old = [saved.get(f"{owner}/{name}") for name in self.saved_fields]
        if f"{owner}/drawn" in saved or not all(isinstance(t, torch.Tensor) for t in old):
            return saved
        if any(t.shape[1:] != getattr(self, name).shape[1:]
               for t, name in zip(old, self.saved_fields, strict=True)):
            return saved  # another model's: the other keys' checks say so
        return {**saved, f"{owner}/drawn": self.column(*(t.to(self.values) for t in old))}

    def column(self, values: torch.Tensor | None = None) -> torch.Tensor:
        return (self.values if values is None else values)[:, self.rows]

    def apply(self, mask: torch.Tensor) -> None:
        current = self.drawn
        new = self.new_values(self.draw().to(self.values.dtype).view(current.shape))
        torch.where(mask.view(-1, *[1] * (current.dim() - 1)), new, current, out=current)
        self.write(current)
        for field in self.fields:
            self.sim.model_changed(field, mask)

    def new_values(self, drawn: torch.Tensor) -> torch.Tensor:
        if self.operation == "scale":
            return self.base * drawn
        if self.operation == "add":
            return self.base + drawn
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

    def column(self, values: torch.Tensor | None = None) -> torch.Tensor:
        return (self.values if values is None else values)[:, self.rows, 0]  # sliding friction

    def write(self, values: torch.Tensor) -> None:
        self.values[:, self.rows, 0] = values


class _AddedToModel(_ModelEvent):
    operation = "add"


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


def _dofs(task: RobotTask, joints: list[str]) -> list[int]:
    """The dofs of the named hinge and slide joints (a free joint's are the base's)."""
    model = task.model
    kinds = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    dofs = [int(model.jnt_dofadr[j]) for j in names.resolve(model, "joint", joints)
            if int(model.jnt_type[j]) in kinds]
    if not dofs:
        raise LabError(f"joints {joints} name no hinge or slide joint",
                       "name the robot's actuated joints")
    return dofs


class _JointEvent(_ModelEvent):
    def __init__(self, task: RobotTask, cfg: c.JointModelEvent):
        self.operation = cfg.operation
        super().__init__(task, _dofs(task, cfg.joints), [cfg.range], cfg.mode)


class randomize_joint_friction(_JointEvent):  # noqa: N801
    field = "dof_frictionloss"
    fields = (field,)


class randomize_joint_damping(_JointEvent):  # noqa: N801
    field = "dof_damping"
    fields = (field,)


class randomize_joint_armature(_JointEvent):  # noqa: N801
    field = "dof_armature"
    fields = (field,)


class randomize_actuator_gains(_ModelEvent):  # noqa: N801
    """A position servo's force is kp (target - q) - kd qdot: MuJoCo's gain kp and biases -kp,
    -kd. Its values are each actuator's (kp, kd): the servos' in the model, then those of the
    motors whose torques lab computes (`ExplicitMotors`' per-env gains)."""

    field = "actuator_gainprm"
    fields = ("actuator_gainprm", "actuator_biasprm")
    saved_fields = ("values", "bias")
    operation = "scale"

    def __init__(self, task: RobotTask, cfg: c.RandomizeActuatorGains):
        model, motors = task.model, task.motors
        named = names.resolve(model, "actuator", cfg.actuators)
        explicit = [k for a in named
                    if motors is not None and (k := motors.column(a)) is not None]
        servos = [a for a in named
                  if model.actuator_gaintype[a] == int(mujoco.mjtGain.mjGAIN_FIXED)
                  and model.actuator_biastype[a] == int(mujoco.mjtBias.mjBIAS_AFFINE)
                  and model.actuator_gainprm[a, 0] > 0
                  and model.actuator_biasprm[a, 1] == -model.actuator_gainprm[a, 0]]
        if not servos and not explicit:
            raise LabError(f"actuators {cfg.actuators} name no position servo or motor model",
                           "randomize_actuator_gains scales the PD gains of position "
                           "actuators and of env.robot's ideal_pd and dc_motor groups")
        self.bias = task.sim.model_field("actuator_biasprm")
        self.motors = motors
        self.explicit = torch.tensor(explicit, dtype=torch.long, device=self.bias.device)
        super().__init__(task, servos, [cfg.stiffness_range, cfg.damping_range], cfg.mode)

    def column(self, values: torch.Tensor | None = None,
               bias: torch.Tensor | None = None) -> torch.Tensor:
        values = self.values if values is None else values
        bias = self.bias if bias is None else bias
        servos = torch.stack([values[:, self.rows, 0], -bias[:, self.rows, 2]], dim=-1)
        if not len(self.explicit):
            return servos
        motors = torch.stack([self.motors.kp[:, self.explicit], self.motors.kd[:, self.explicit]],
                             dim=-1).to(servos.dtype)
        return torch.cat([servos, motors], dim=1)

    def write(self, values: torch.Tensor) -> None:
        servos, motors = values[:, :len(self.rows)], values[:, len(self.rows):]
        self.values[:, self.rows, 0] = servos[..., 0]
        self.bias[:, self.rows, 1] = -servos[..., 0]
        self.bias[:, self.rows, 2] = -servos[..., 1]
        if len(self.explicit):
            self.motors.kp[:, self.explicit] = motors[..., 0].to(self.motors.kp.dtype)
            self.motors.kd[:, self.explicit] = motors[..., 1].to(self.motors.kd.dtype)


class encoder_bias:  # noqa: N801 - a term, named as mjlab's
    carried = ("bias",)

    def __init__(self, task: RobotTask, cfg: c.EncoderBias):
        robot = task.robot
        joints = set(names.resolve(task.model, "joint", cfg.joints))
        columns = [i for i, j in enumerate(robot.joint_ids) if j in joints]
        if not columns:
            raise LabError(f"env.events' encoder bias names joints {cfg.joints}, none of them "
                           "actuated", f"name some of {', '.join(robot.joint_names)}")
        self.bias = robot.encoder_bias
        self.mask = torch.zeros_like(self.bias[0]).index_fill_(
            0, torch.tensor(columns, device=self.bias.device), 1.0)
        self.draw = Uniform(task, [cfg.bias_range] * self.bias.shape[1])
        self.everyone = torch.ones(task.num_envs, dtype=torch.bool, device=self.bias.device)
        if cfg.bias_range == (0.0, 0.0):
            return  # the encoders read true: nothing is drawn, the random streams stay as they are
        robot.biased = True
        if cfg.mode == "reset":
            self.reset = self.apply
        else:  # RobotTask runs it once, at the env's first reset
            self.startup = lambda: self.apply(self.everyone)

    def apply(self, mask: torch.Tensor) -> None:
        drawn = self.draw().mul_(self.mask).to(self.bias.dtype)
        torch.where(mask[:, None], drawn, self.bias, out=self.bias)
