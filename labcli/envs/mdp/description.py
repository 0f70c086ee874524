"""A robot's description, as a task's config holds it (`env.robot`, `--set env.robot...`): its
actuated joints grouped by motor, with effort and velocity limits, armature (the rotor's inertia
reflected through the gearbox) and PD gains, each joint's action scale, and the model's parts the
terms name (feet, contact bodies, the collision set). `labcli.envs.mdp.robot_model` writes it
into the model's MjSpec before compiling.

pydantic only (no torch, no MuJoCo), as the terms' configs: a task's config imports it.
"""

from __future__ import annotations

import math
import re
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

Patterns = list[str]
# How a group's joint torques arise (Isaac Lab's and mjlab's actuator models): `implicit`,
# MuJoCo's position servo, its damping integrated implicitly; the others are computed by lab at
# every physics step from the state then and sent to a plain motor: `ideal_pd`, the PD law
# clipped to the effort limit; `dc_motor`, that torque within the motor's torque-speed line;
# `mlp`, a learned actuator net over the history of position errors and velocities.
ActuatorModel = Literal["implicit", "ideal_pd", "dc_motor", "mlp"]


class ActuatorNet(BaseModel):
    """A learned actuator model (Isaac Lab's `ActuatorNetMLP`, mjlab's `LearnedMlpActuator`):
    a TorchScript network that maps, per joint, the position errors (target - position) and
    velocities of chosen past physics steps to the joint's torque."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)

    file: str = Field(min_length=1, description="the TorchScript network (torch.jit.save)")
    input_order: Literal["pos_vel", "vel_pos"] = Field("pos_vel", description="which half of "
                                                       "the input comes first")
    input_idx: list[int] = Field([0, 1, 2], min_length=1, description="physics steps back "
                                 "(0: now) of each input; the history holds max + 1")
    pos_scale: float = Field(1.0, description="times the position errors, rad")
    vel_scale: float = Field(1.0, description="times the velocities, rad/s")
    torque_scale: float = Field(1.0, description="times the network's output, N m")

    @model_validator(mode="after")
    def _indices(self) -> ActuatorNet:
        if min(self.input_idx) < 0:
            raise ValueError("input_idx counts physics steps back from 0 (now): no negatives")
        return self


class Actuators(BaseModel):
    """The joints one kind of motor drives (names or regular expressions matched whole) and
    that motor's numbers. Gains left out follow from the armature (as mjlab's robots): a
    stiffness of armature x (2 pi f)^2 and a damping of 2 zeta x armature x 2 pi f, for the
    robot's natural frequency f and damping ratio zeta. An action scale left out is a quarter
    of the effort limit over the stiffness (mjlab's): an action of 1 asks for a quarter of the
    motor's torque."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)

    joints: Patterns = Field(min_length=1)
    effort_limit: float = Field(gt=0, description="N m (N for a slide joint)")
    velocity_limit: float | None = Field(None, gt=0, description="rad/s (m/s), the motor's")
    armature: float = Field(ge=0, description="reflected rotor inertia, kg m^2")
    stiffness: float | None = Field(None, ge=0, description="kp, N m/rad; None: from armature")
    damping: float | None = Field(None, ge=0, description="kd, N m s/rad; None: from armature")
    action_scale: float | None = Field(None, gt=0, description="rad per unit of action; None: "
                                       "0.25 x effort_limit / stiffness")
    # The joint's own losses, beside the servo's kd: Menagerie's Go1 and Go2 add damping 2 and
    # frictionloss 0.2 to every joint, which mjlab's copy of the Go1 leaves out.
    viscous_damping: float | None = Field(None, ge=0, description="the joint's passive damping, "
                                          "N m s/rad; None: the model's")
    frictionloss: float | None = Field(None, ge=0, description="the joint's dry friction, N m; "
                                       "None: the model's")
    clip_targets: bool = Field(True, description="implicit: the servo's targets held to the "
                               "control range the model gives its actuator (Menagerie's: "
                               "mostly the joint's range); False: any target, as mjlab's and "
                               "Isaac Lab's servos take them, so a gripper closing on an "
                               "object can squeeze it with up to effort_limit")
    model: ActuatorModel = Field("implicit", description="implicit: MuJoCo's position servo; "
                                 "ideal_pd, dc_motor, mlp: torques lab computes each physics "
                                 "step (see labcli.envs.mdp.motors)")
    saturation_effort: float | None = Field(None, gt=0, description="dc_motor, mlp: the "
                                            "motor's torque at rest, N m; None: effort_limit")
    network: ActuatorNet | None = Field(None, description="mlp: the learned actuator net")

    @model_validator(mode="after")
    def _model_complete(self) -> Actuators:
        if self.model == "dc_motor" and self.velocity_limit is None:
            raise ValueError("a dc_motor needs velocity_limit: its torque falls to 0 there")
        if self.model == "mlp" and self.network is None:
            raise ValueError("an mlp actuator needs network (its TorchScript file and inputs)")
        return self

    @property
    def explicit(self) -> bool:
        """Whether lab computes this group's torques (every model but `implicit`)."""
        return self.model != "implicit"

    def gains(self, frequency_hz: float, damping_ratio: float) -> tuple[float, float]:
        """(kp, kd): as given, else derived from the armature."""
        omega = 2.0 * math.pi * frequency_hz
        kp = self.stiffness if self.stiffness is not None else self.armature * omega**2
        kd = (self.damping if self.damping is not None
              else 2.0 * damping_ratio * self.armature * omega)
        return kp, kd

    def scale(self, frequency_hz: float, damping_ratio: float) -> float:
        if self.action_scale is not None:
            return self.action_scale
        kp, _ = self.gains(frequency_hz, damping_ratio)
        if kp <= 0:
            raise ValueError("an action scale derived from a stiffness of 0 is infinite: give "
                             "action_scale, a stiffness or an armature")
        return 0.25 * self.effort_limit / kp


GeomType = Literal["plane", "hfield", "sphere", "capsule", "ellipsoid", "cylinder", "box", "mesh",
                   "sdf"]


class Collisions(BaseModel):
    """How the robot's collision geoms of some bodies touch (mjlab's CollisionCfg): geoms are
    matched by their body (Menagerie's geoms often have no name) and optionally their type."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)

    bodies: Patterns = Field(min_length=1, description="bodies whose geoms these are")
    types: list[GeomType] | None = Field(None, description="only geoms of these types; None: "
                                         "any")
    collide: bool = Field(True, description="false: they touch nothing (contype and "
                          "conaffinity 0)")
    condim: Literal[1, 3, 4, 6] | None = Field(None, description="contact dimensions: 3 "
                                               "sliding friction, 4 torsional too, 6 rolling "
                                               "too; None: the model's")
    friction: tuple[float, float, float] | None = Field(None, description="sliding, torsional "
                                                        "and rolling; None: the model's")
    solref: tuple[float, float] | None = Field(None, description="contact stiffness: time "
                                               "constant (s) and damping ratio")
    priority: int | None = Field(None, description="in a contact, the geom of higher "
                                 "priority gives its condim and friction")


class Site(BaseModel):
    """A site the description adds to one of the robot's bodies (a point terms read, such as
    the middle of a gripper's pads), in the body's frame."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)

    body: str = Field(min_length=1)
    pos: tuple[float, float, float] = Field(description="m, in the body's frame")
    quat: tuple[float, float, float, float] = Field((1.0, 0.0, 0.0, 0.0), description="w, x, "
                                                    "y, z, in the body's frame")


class RobotDescription(BaseModel):
    """What a task needs to know of its robot beyond the MJCF, in one place a user can read and
    change. `base`: how the robot's root moves: `floating`, a free joint (legged robots);
    `planar`, slide and hinge joints in a plane (Hopper, Walker2d); `fixed`, bolted to the world
    (an arm). The model must agree: a floating base has a free joint, the others none."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)

    base: Literal["floating", "planar", "fixed"] = "floating"
    natural_frequency_hz: float = Field(10.0, gt=0, description="of the derived PD gains")
    damping_ratio: float = Field(2.0, gt=0, description="of the derived PD gains")
    actuators: dict[str, Actuators] = Field(min_length=1, description="by motor: the first "
                                            "group whose patterns match a joint drives it")
    feet: Patterns = Field(default_factory=list, description="sites at the soles")
    foot_bodies: Patterns = Field(default_factory=list, description="bodies whose contacts "
                                  "with the ground are the feet's")
    contact_pairs: Patterns | None = Field(None, description="the model's explicit contact "
                                           "pairs to keep, by name; None: all of them")
    sites: dict[str, Site] = Field(default_factory=dict, description="sites to add, by name")
    collisions: list[Collisions] | None = Field(None, description="the collision set: each of "
                                                "the robot's collision geoms set by the first "
                                                "entry that matches it, those none matches "
                                                "touching nothing (only a gripper's, say, for "
                                                "speed); None: the model's own")
    gravity_compensation: bool | None = Field(None, description="True: the robot's bodies "
                                              "weigh nothing on its joints (MuJoCo's gravcomp), "
                                              "as a Franka's own controller cancels gravity; "
                                              "what it holds still weighs. False: every body "
                                              "weighs. None: as the model says")
    home: dict[str, float] | None = Field(None, description="the default pose: joint "
                                          "positions (rad, m) by name or pattern, written as "
                                          "the model's keyframe 'home' (the others at qpos0); "
                                          "None: the model's own keyframes")
    mirror: dict[str, str] = Field(default_factory=dict, description="the robot's left-right "
                                   "symmetry: a joint's mirror image by name, each pattern "
                                   "(searched) replaced as re.sub does, e.g. {'^left_': "
                                   "'right_', '^right_': 'left_'}; a joint no pattern matches "
                                   "is its own image; empty: not declared symmetric")
    mirror_negated: Patterns = Field(default_factory=list, description="joints whose angle "
                                     "changes sign in the mirror image: those turning about "
                                     "the base's x or z axis (roll, yaw, abduction)")

    @model_validator(mode="after")
    def _scales_finite(self) -> RobotDescription:
        for actuators in self.actuators.values():
            actuators.scale(self.natural_frequency_hz, self.damping_ratio)
        return self

    def mirrored(self, joint: str) -> tuple[str, float]:
        """`joint`'s mirror image (a joint's name) and the sign its angle takes there."""
        image = next((re.sub(p, r, joint, count=1) for p, r in self.mirror.items()
                      if re.search(p, joint)), joint)
        return image, -1.0 if any(re.fullmatch(p, joint) for p in self.mirror_negated) else 1.0

    def group_of(self, joint: str) -> tuple[str, Actuators] | None:
        """The first group whose patterns match `joint` whole; None if none does."""
        for name, group in self.actuators.items():
            if any(re.fullmatch(p, joint) for p in group.joints):
                return name, group
        return None
