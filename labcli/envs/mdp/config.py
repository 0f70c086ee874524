"""The settings of a robot task's terms, as `--set env.<group>.<term>.<key>=VALUE` sets them.

pydantic only (no torch, no MuJoCo): a task's config imports these, and `lab train` validates
its configs before it imports torch. Each term's code is named by its class's `impl`, a
"module:name" reference resolved when the env is built (labcli/envs/mdp/task.py). A group is a
pydantic model whose fields are its terms, in order; a field set to None (`--set
env.rewards.energy=null`) leaves that term out.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from labcli.envs.config import TaskConfig
from labcli.envs.mdp.description import RobotDescription
from labcli.envs.mdp.terrain import TerrainConfig

Range = tuple[float, float]
# What an actor-critic's critic reads (RobotTaskConfig.critic_observations).
CriticInput = Literal["policy", "noise_free", "privileged"]
# Body names or patterns (regular expressions matched whole): at least one.
Bodies = Annotated[list[str], Field(min_length=1)]
# Site names or patterns, likewise.
Sites = Annotated[list[str], Field(min_length=1)]


class Term(BaseModel):
    """A term's parameters; `impl` names the code that computes it."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)
    impl: ClassVar[str]


def _check_range(name: str, value: Range | None) -> None:
    if value is not None and value[0] > value[1]:
        raise ValueError(f"{name} is ({value[0]:g}, {value[1]:g}): its low end is above its "
                         f"high end; give (low, high)")


class RangeChecked(Term):
    """Checks every field holding a (low, high) range, or a mapping of them."""

    @model_validator(mode="after")
    def _ranges_ordered(self) -> RangeChecked:
        for name, value in self:
            if isinstance(value, dict):
                for key, item in value.items():
                    _check_range(f"{name}.{key}", item)
            elif isinstance(value, tuple) and len(value) == 2:
                _check_range(name, value)
        return self


# commands -------------------------------------------------------------------------------------
class UniformVelocityCommand(RangeChecked):
    """Isaac Lab's UniformVelocityCommand: a base velocity to track (lin x, lin y in m/s, yaw
    rate in rad/s, in the base's frame) drawn per env from these ranges at reset and every
    `resampling_time_range` s. A share of envs stands (command 0); in a share of the others,
    with `heading_command`, the yaw rate steers toward a drawn heading instead
    (`heading_control_stiffness` x the heading error, clipped to `ang_vel_z`). A share
    `rel_forward_envs` of the draws is made forward-only (mjlab's): lin x is |lin x| and at
    least 0.3 m/s, lin y and the yaw rate 0 (a heading env's yaw rate still steers). Logs each
    episode's mean tracking errors as Metrics/<name>/error_vel_xy and .../error_vel_yaw; with
    `error_window` > 0 s each step's error (command minus base velocity) is first averaged
    over about that long (an exponential average), so that a gait whose base sways and turns
    with every step is judged by the velocity it keeps over a stride. Rewards see each step's
    error either way."""

    impl: ClassVar[str] = "labcli.envs.mdp.commands:UniformVelocityCommand"
    resampling_time_range: Range = (10.0, 10.0)
    rel_standing_envs: float = Field(0.02, ge=0, le=1)
    rel_heading_envs: float = Field(1.0, ge=0, le=1)
    rel_forward_envs: float = Field(0.0, ge=0, le=1)
    heading_command: bool = True
    heading_control_stiffness: float = Field(0.5, ge=0)
    lin_vel_x: Range = (-1.0, 1.0)
    lin_vel_y: Range = (-1.0, 1.0)
    ang_vel_z: Range = (-1.0, 1.0)
    heading: Range = (-math.pi, math.pi)
    error_window: float = Field(0.0, ge=0.0)


class UniformPoseCommand(RangeChecked):
    """Isaac Lab's UniformPoseCommand: a target pose for a site (an end effector) or a body (an
    object to carry there), in the frame of the fixed base's body `base_body`: a position drawn
    in the box of `pos_x`, `pos_y`, `pos_z` (m) and an orientation of a roll, pitch and yaw
    (rad, extrinsic x-y-z) drawn in theirs, per env at reset and every
    `resampling_time_range` s. The command is the position and the unit quaternion (w, x, y,
    z). Logs each episode's final position and orientation errors of the site or body as
    Metrics/<name>/position_error (m) and .../orientation_error (rad), and with
    `reached_within` the share of episodes whose site or body came that close to its last
    target at any step since it was drawn as .../reached (mjlab's latched `episode_success`);
    videos show the target as a marker."""

    impl: ClassVar[str] = "labcli.envs.mdp.commands:UniformPoseCommand"
    site: str | None = Field(None, min_length=1, description="the site whose pose is "
                             "commanded (or give body)")
    body: str | None = Field(None, min_length=1, description="the body whose pose is "
                             "commanded (or give site)")
    base_body: str = Field(min_length=1, description="the fixed base's body: the frame")
    resampling_time_range: Range = (4.0, 4.0)
    pos_x: Range = (0.35, 0.65)
    pos_y: Range = (-0.2, 0.2)
    pos_z: Range = (0.15, 0.5)
    roll: Range = (0.0, 0.0)
    pitch: Range = (math.pi, math.pi)
    yaw: Range = (-math.pi, math.pi)
    place: dict[str, Range] | None = Field(None, description="with `body` an object: each "
                                           "target drawn during an episode also drops the "
                                           "object anew, at rest at its default pose plus "
                                           "offsets drawn from these ranges (keys as "
                                           "ResetRootUniform's pose_range: mjlab's "
                                           "LiftingCommand), in the next step's physics")
    reached_within: float | None = Field(None, gt=0, description="m: log Metrics/<name>/"
                                         "reached, whether the position came this close to "
                                         "the last target since it was drawn")

    @model_validator(mode="after")
    def _one_frame(self) -> UniformPoseCommand:
        if (self.site is None) == (self.body is None):
            raise ValueError("a pose command tracks a site or a body: give one of site and "
                             "body, not " + ("both" if self.site else "neither"))
        if self.place is not None:
            if self.body is None:
                raise ValueError("place drops the commanded object anew: it needs body (an "
                                 "object with a free joint), not site")
            check_pose_keys("place", self.place)
        return self

    @property
    def frame(self) -> tuple[str, str]:
        """What the command tracks: the sensors' object type and its name."""
        return ("site", self.site) if self.site is not None else ("xbody", self.body)


class CommandRef(Term):
    """A term about one of the task's commands, by its name in env.commands."""

    command: str = "base_velocity"


class PoseCommandRef(CommandRef):
    command: str = "ee_pose"


# observations ---------------------------------------------------------------------------------
MOUNTING_KEYS = ("roll", "pitch", "yaw")


class ObsTerm(RangeChecked):
    """An observation term, as Isaac Lab's: its value plus uniform noise in (-noise, noise)
    (with the task's `observation_noise` on: training; `lab play` turns it off unless asked),
    clipped to `clip`, times `scale`. `bias`: also an offset per column held through each
    episode, uniform in (-bias, bias) drawn at its start (an encoder's or an IMU's calibration
    error; with `observation_noise` too). `history_length` k > 1: the policy sees the term's
    last k frames (each after bias, noise, clip and scale), oldest first, as Isaac Lab's.
    `delay`: (low, high) control steps by which the term's frames reach the policy late (a
    sensor's latency), drawn per env at every episode's start, as mjlab's `delay_min_lag` /
    `delay_max_lag`. An episode's first frame stands for the ones before it."""

    # The raw value's unit and convention, per column (before noise, clip and scale), which
    # `lab export` writes for deployers; a term made per column may give `units` instead.
    unit: ClassVar[str] = ""
    # How the term's columns change in the robot's left-right mirror image (`symmetry.py`):
    # "even" (they do not), "polar" (a vector in the base's frame: y flips), "axial" (an
    # angular one: x and z flip), "joints" (one column per actuated joint, or action, as the
    # robot description mirrors the joints), "scan" (a grid of points: y flips), "command"
    # (the command's own); None: not known, and symmetric training refuses the term.
    mirror: ClassVar[str | None] = None
    scale: float = 1.0
    clip: Range | None = None
    noise: float = Field(0.0, ge=0.0)
    bias: float = Field(0.0, ge=0.0)
    history_length: int = Field(0, ge=0, description="frames of the term the policy sees, "
                                "oldest first (0 or 1: the current one)")
    delay: tuple[int, int] = Field((0, 0), description="control steps (low, high) by which "
                                   "the term's frames lag, drawn per env each episode")

    @model_validator(mode="after")
    def _delay_not_negative(self) -> ObsTerm:
        if self.delay[0] < 0:
            raise ValueError(f"delay is {self.delay} control steps: give (low, high) with "
                             "0 <= low <= high")
        return self

    @property
    def frames(self) -> int:
        """Frames of the term in the policy's input."""
        return max(self.history_length, 1)


class BaseHeight(ObsTerm):
    """The root's height (m) above the ground under it: the terrain's surface, else z = 0."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:base_height"
    mirror: ClassVar[str | None] = "even"
    unit: ClassVar[str] = "m, the root above the ground under it"


class BaseLinVel(ObsTerm):
    """The root body's linear velocity in its own frame (m/s)."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:base_lin_vel"
    mirror: ClassVar[str | None] = "polar"
    unit: ClassVar[str] = "m/s, root frame"


class BaseAngVel(ObsTerm):
    """The root body's angular velocity in its own frame (rad/s)."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:base_ang_vel"
    mirror: ClassVar[str | None] = "axial"
    unit: ClassVar[str] = "rad/s, root frame"


class ProjectedGravity(ObsTerm):
    """Gravity's direction (a unit vector) in the root's frame: (0, 0, -1) when upright. With
    `site`, in the frame of that site of the root body instead: an IMU's (Menagerie's Go1
    `imu`, G1 `imu_in_pelvis`). `mounting_range`: the IMU mounted turned by a roll, pitch and
    yaw (rad) drawn per env at every episode's start, uniform in each key's range."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:projected_gravity"
    mirror: ClassVar[str | None] = "polar"
    unit: ClassVar[str] = "gravity's unit vector, root frame (with a site: the site's)"
    site: str | None = Field(None, description="an IMU site: gravity in its frame")
    mounting_range: dict[str, Range] = Field(
        default_factory=dict, description="roll, pitch, yaw (rad) of the IMU's mounting")

    @model_validator(mode="after")
    def _mounting_keys(self) -> ProjectedGravity:
        unknown = set(self.mounting_range) - set(MOUNTING_KEYS)
        if unknown:
            raise ValueError(f"mounting_range has {', '.join(sorted(unknown))}: its keys are "
                             f"{', '.join(MOUNTING_KEYS)}")
        return self


class BaseYawRoll(ObsTerm):
    """The root's yaw and roll (rad)."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:base_yaw_roll"
    unit: ClassVar[str] = "rad"


class Target(Term):
    """A term about a target position in the world (Isaac Lab's classic tasks: far ahead)."""

    target: tuple[float, float, float] = (1000.0, 0.0, 0.0)


class TargetObs(Target, ObsTerm):
    pass


class AngleToTarget(TargetObs):
    """The horizontal angle (rad, in (-pi, pi]) from the root's heading to the target."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:base_angle_to_target"
    unit: ClassVar[str] = "rad to the target, wrapped to [-pi, pi)"


class UpProj(ObsTerm):
    """The root's up (z) axis projected on the world's: 1 upright, 0 on its side."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:base_up_proj"
    unit: ClassVar[str] = "cosine of the root's tilt"


class HeadingProj(TargetObs):
    """The root's forward (x) axis projected on the horizontal direction to the target."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:base_heading_proj"
    unit: ClassVar[str] = "cosine of the angle from the root's x axis to the target"


class HeightScan(ObsTerm):
    """The terrain around the base, as Isaac Lab's height scanner sees it: the base's height
    above the terrain at a yaw-aligned grid of points (`length` metres along the base's x by
    `width` along its y, every `resolution`; by default 17 × 11 = 187), minus `offset`. Point
    order: x (back to front) fastest, then y (right to left). Needs env.terrain."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:height_scan"
    mirror: ClassVar[str | None] = "scan"
    unit: ClassVar[str] = "m, the root above the terrain at each point, minus offset"
    length: float = Field(1.6, ge=0, description="m along the base's x")
    width: float = Field(1.0, ge=0, description="m along the base's y")
    resolution: float = Field(0.1, gt=0, description="m between points")
    offset: float = Field(0.5, description="m subtracted from every height")
    noise: float = Field(0.1, ge=0.0)
    clip: Range | None = (-1.0, 1.0)


class JointPos(ObsTerm):
    """Joint positions relative to the default pose (rad or m); `biased`: as the encoders read
    them, off by the encoder bias an `EncoderBias` event draws (mjlab's `joint_pos_rel` with
    `biased`)."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:joint_pos_rel"
    mirror: ClassVar[str | None] = "joints"
    unit: ClassVar[str] = "rad (m for a slide joint) from the default pose"
    biased: bool = False


class JointPosNormalized(ObsTerm):
    """Joint positions mapped from their limits to [-1, 1]."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:joint_pos_limit_normalized"
    mirror: ClassVar[str | None] = "joints"
    unit: ClassVar[str] = "-1 to 1 over the joint's range"


class JointVel(ObsTerm):
    """Joint velocities (rad/s or m/s)."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:joint_vel_rel"
    mirror: ClassVar[str | None] = "joints"
    unit: ClassVar[str] = "rad/s (m/s for a slide joint)"


class GeneratedCommands(CommandRef, ObsTerm):
    """The named command's current value (Isaac Lab's `generated_commands`)."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:generated_commands"
    mirror: ClassVar[str | None] = "command"


class LastAction(ObsTerm):
    """The action of the last step, as the policy sent it (before scaling)."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:last_action"
    mirror: ClassVar[str | None] = "joints"
    unit: ClassVar[str] = "the policy's last action"


class ObjectTerm(Term):
    """A term about a free body the robot handles (a cube), by its body's name."""

    object: str = Field(min_length=1, description="the object's body (it has a free joint)")


class ObjectPosition(ObjectTerm, ObsTerm):
    """The object's position in the frame of the fixed base's body `base_body` (m): Isaac
    Lab's `object_position_in_robot_root_frame`."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:object_position_in_robot_root_frame"
    unit: ClassVar[str] = "m, base frame"
    base_body: str = Field(min_length=1, description="the fixed base's body: the frame")


class ObjectFromSite(ObjectTerm, ObsTerm):
    """The object's position from the site (an end effector), in the frame of the fixed
    base's body `base_body` (m): mjlab's `ee_to_object_distance`."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:object_from_site"
    unit: ClassVar[str] = "m, base frame"
    site: str = Field(min_length=1, description="the end effector's site")
    base_body: str = Field(min_length=1, description="the fixed base's body: the frame")


class ObjectToTarget(PoseCommandRef, ObjectTerm, ObsTerm):
    """The command's target position from the object, in the frame of the command's base
    body (m): mjlab's `object_to_goal_distance`."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:object_to_target"
    unit: ClassVar[str] = "m, base frame"
    command: str = "object_pose"


class BodyWrench(ObsTerm):
    """The force and torque each named body receives from its parent through its joint, in the
    body's frame (N, N m): Isaac Lab's `body_incoming_wrench`, read from MuJoCo force and torque
    sensors that the task adds to the model."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:body_incoming_wrench"
    bodies: Bodies


class ContactForces(ObsTerm):
    """The net contact force on each named body (N, world frame), from MuJoCo contact sensors
    that the task adds to the model."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:contact_forces"
    unit: ClassVar[str] = "N, world frame"
    bodies: Bodies


class FootObs(ObsTerm):
    """A term about each foot, one column (or three) per foot in the model's order: `bodies`,
    whose subtrees' contacts with the terrain MuJoCo's contact sensors find (as the foot reward
    terms'). The feet's mirror image is the robot description's mirror of their names. mjlab's
    critic reads these (`env.critic_extras`). Read from MuJoCo sensors, which a physics step
    computes at its start: one physics step behind the state, and at an episode's first state
    still the state before the reset (mjlab runs MuJoCo's forward pass before its
    observations)."""

    mirror: ClassVar[str | None] = "feet"
    bodies: Bodies


class FootHeight(FootObs):
    """Each foot's site above the terrain under it (m; flat ground: the site's z), one site on
    each foot: mjlab's `foot_height`."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:foot_height"
    unit: ClassVar[str] = "m, the foot's site above the ground under it"
    sites: Sites


class FootAirTime(FootObs):
    """Each foot's time in the air up to the step's end (s; 0 while it touches): mjlab's
    `foot_air_time`."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:foot_air_time"
    unit: ClassVar[str] = "s in the air"


class FootContact(FootObs):
    """1 where the foot touches the terrain, else 0: mjlab's `foot_contact`."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:foot_contact"
    unit: ClassVar[str] = "1 touching, 0 not"


class FootContactForces(FootObs):
    """Each foot's net contact force with the terrain, world frame, each component as
    sign(f) log(1 + |f|): mjlab's `foot_contact_forces`. A world-frame vector has no mirror
    image in the base's frame: symmetric training refuses it."""

    impl: ClassVar[str] = "labcli.envs.mdp.observations:foot_contact_forces"
    mirror: ClassVar[str | None] = None
    unit: ClassVar[str] = "sign(f) log(1 + |f| / N), world frame"


# rewards ---------------------------------------------------------------------------------------
class RewardTerm(Term):
    """A reward term: its unweighted value per env step, times `weight`."""

    weight: float


class Alive(RewardTerm):
    """1 every step, a terminating one included."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:is_alive"


class Progress(Target, RewardTerm):
    """The step's reduction of the horizontal distance to the target, divided by the step's
    duration (m/s): Isaac Lab's `progress_reward`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:progress_reward"


class Upright(RewardTerm):
    """1 where the root's up axis projects on the world's above `threshold`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:upright_posture_bonus"
    threshold: float = 0.93


class MoveToTarget(Target, RewardTerm):
    """The heading's projection on the direction to the target over `threshold`, capped at 1."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:move_to_target_bonus"
    threshold: float = Field(0.8, gt=0)


class ActionL2(RewardTerm):
    """The squared norm of the action."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:action_l2"


class ActionRateL2(RewardTerm):
    """The squared norm of the action's change since the last step."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:action_rate_l2"


class GearWeighted(RewardTerm):
    """Per joint, its actuator's gear over the largest gear (Isaac Lab's `gear_ratio_scaled`)."""


class Energy(GearWeighted):
    """sum |action x joint velocity x gear ratio|: Isaac Lab's `power_consumption`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:power_consumption"


class JointPosLimits(GearWeighted):
    """Over the joints past `threshold` of their normalized range, how far past, scaled to the
    rest of the range and weighted by gear ratio: Isaac Lab's `joint_pos_limits_penalty_ratio`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:joint_pos_limits_penalty_ratio"
    threshold: float = Field(0.99, gt=0, lt=1)


class JointTorquesL2(RewardTerm):
    """sum of squared actuator torques at the joints (N m), from MuJoCo actuator-force sensors."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:joint_torques_l2"


class JointVelL2(RewardTerm):
    """sum of squared joint velocities ((rad/s)^2): Isaac Lab's `joint_vel_l2`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:joint_vel_l2"


class PositionCommandError(PoseCommandRef, RewardTerm):
    """The distance (m) from the commanded site to its target position: Isaac Lab's
    `position_command_error`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:position_command_error"


class PositionCommandErrorTanh(PoseCommandRef, RewardTerm):
    """1 - tanh(distance to the target position / std): Isaac Lab's
    `position_command_error_tanh`, which rewards the last centimetres."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:position_command_error_tanh"
    std: float = Field(0.1, gt=0, description="m")


class OrientationCommandError(PoseCommandRef, RewardTerm):
    """The angle (rad) between the site's orientation and the target's: Isaac Lab's
    `orientation_command_error`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:orientation_command_error"


class ObjectReach(ObjectTerm, RewardTerm):
    """1 - tanh(distance from the site (an end effector) to the object / std): Isaac Lab's
    `object_ee_distance`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:object_ee_distance"
    site: str = Field(min_length=1, description="the end effector's site")
    std: float = Field(0.1, gt=0, description="m")


class GraspTerm(ObjectTerm):
    """A term that asks whether fingers hold the object: each of them touches it."""

    squeeze: float | None = Field(None, gt=0, le=1, description="where given, the fingers "
                                  "must also push the object from opposing sides: their "
                                  "contacts' net force at most this share of the sum of their "
                                  "sizes (the YAM's pads holding a 50 g cube in the air: 0.2; "
                                  "both fingertips pressing it into the floor: 0.98-1.0); "
                                  "None: touching is enough")


class HeldObjectTerm(GraspTerm):
    """A term about an object that counts only while held, where `held_by` is given."""

    held_by: list[str] | None = Field(None, min_length=1, description="finger bodies that must "
                                      "all touch the object (and squeeze it, where `squeeze` "
                                      "is given) for it to count (a batted object does not); "
                                      "None: any")


class ObjectGrasped(GraspTerm, RewardTerm):
    """1 where each of the `fingers` bodies touches the object: robosuite Lift's grasp
    reward. Fingertips that press the object down touch it too: `squeeze` tells them from a
    grasp."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:object_grasped"
    fingers: list[str] = Field(min_length=1, description="the gripper's finger bodies")


class ObjectLifted(HeldObjectTerm, RewardTerm):
    """1 where the object's origin is above `minimal_height` (m, world z): Isaac Lab's
    `object_is_lifted`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:object_is_lifted"
    minimal_height: float = Field(0.04, description="m")


class ObjectGoalDistance(PoseCommandRef, HeldObjectTerm, RewardTerm):
    """Where the object is lifted (above `minimal_height`; None: anywhere), a kernel of its
    distance d to the command's target position: `tanh`, 1 - tanh(d / std) (Isaac Lab's
    `object_goal_distance`); `gaussian`, exp(-d^2 / std^2) (mjlab's `bring_object_reward`,
    with no minimal height)."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:object_goal_distance"
    command: str = "object_pose"
    std: float = Field(0.3, gt=0, description="m")
    minimal_height: float | None = Field(0.04, description="m")
    kernel: Literal["tanh", "gaussian"] = "tanh"


class ObjectStagedReach(PoseCommandRef, ObjectTerm, RewardTerm):
    """reach x (1 + bring), both Gaussian kernels: reach = exp(-|site - object|^2 /
    reaching_std^2), bring = exp(-|target - object|^2 / bringing_std^2). Bringing pays only
    near the object, so the hand learns to reach it before carrying it: mjlab's
    `staged_position_reward`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:staged_position_reward"
    command: str = "object_pose"
    site: str = Field(min_length=1, description="the end effector's site")
    reaching_std: float = Field(0.2, gt=0, description="m")
    bringing_std: float = Field(0.3, gt=0, description="m")


class JointVelHinge(RewardTerm):
    """sum over the actuated joints of (|velocity| - max_vel)^2 where it exceeds max_vel
    ((rad/s)^2): mjlab's `joint_velocity_hinge_penalty`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:joint_vel_hinge"
    max_vel: float = Field(0.5, ge=0, description="rad/s (m/s for a slide joint)")


class JointAccL2(RewardTerm):
    """sum of squared joint accelerations over the env step ((rad/s^2)^2)."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:joint_acc_l2"


# What "upright" is measured against: the world's up, or the terrain's normal under the base
# (its slope over `span` metres each way, from env.terrain): upright on a slope is then
# square to the slope.
Reference = Literal["gravity", "terrain"]


class FlatOrientationL2(RewardTerm):
    """The squared horizontal part of gravity in the root's frame (with `reference` terrain:
    of the terrain's normal under the base)."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:flat_orientation_l2"
    reference: Reference = "gravity"
    span: float = Field(0.3, gt=0, description="m each way over which the terrain's slope "
                        "is taken")


class LinVelZL2(RewardTerm):
    """The root's vertical velocity squared, in its own frame ((m/s)^2)."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:lin_vel_z_l2"


class AngVelXYL2(RewardTerm):
    """The root's roll and pitch rates squared, summed, in its own frame ((rad/s)^2)."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:ang_vel_xy_l2"


class TrackLinVelXYExp(CommandRef, RewardTerm):
    """exp(-|command xy - base linear velocity xy|^2 / std^2), in the base's frame."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:track_lin_vel_xy_exp"
    std: float = Field(0.5, gt=0)


class TrackAngVelZExp(CommandRef, RewardTerm):
    """exp(-(command yaw rate - base yaw rate)^2 / std^2)."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:track_ang_vel_z_exp"
    std: float = Field(0.5, gt=0)


class Contacts(Term):
    """A term about the contacts of named bodies (patterns) with anything: a body is in contact
    where the net force of its contacts exceeds `threshold` (N), read from MuJoCo contact
    sensors that the task adds to the model."""

    bodies: Bodies
    threshold: float = Field(1.0, ge=0)


class FeetAirTime(CommandRef, Contacts, RewardTerm):
    """At each foot's touchdown, its time in the air minus `threshold_s` (s), summed over the
    feet; 0 while the command's xy speed is under 0.1 m/s: Isaac Lab's `feet_air_time`, over
    env steps (a touchdown counts the step it lands in)."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:feet_air_time"
    threshold_s: float = Field(0.5, ge=0)


class UndesiredContacts(Contacts, RewardTerm):
    """The number of named bodies in contact (Isaac Lab's `undesired_contacts`)."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:undesired_contacts"


# mjlab's velocity task (tasks/velocity/mdp/rewards.py, envs/mdp/rewards.py), as its G1 uses it.
class TrackLinearVelocity(CommandRef, RewardTerm):
    """exp(-(|command xy - base linear velocity xy|^2 + base z velocity^2) / std^2), in the
    base's frame (m/s): mjlab's `track_linear_velocity` (the command's z velocity is 0)."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:track_linear_velocity"
    std: float = Field(0.5, gt=0)


class TrackAngularVelocity(CommandRef, RewardTerm):
    """exp(-((command yaw rate - base yaw rate)^2 + |base angular velocity xy|^2) / std^2), in
    the base's frame (rad/s): mjlab's `track_angular_velocity`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:track_angular_velocity"
    std: float = Field(math.sqrt(0.5), gt=0)


class UprightExp(RewardTerm):
    """exp(-|xy of gravity's direction in the body's frame|^2 / std^2): 1 upright, falling off
    with the tilt (|xy|^2 is sin^2 of it), on flat ground: mjlab's `upright`. `body`: None for
    the root (the G1's recipe names "torso_link"). With `reference` terrain, the terrain's
    normal under the root in place of gravity's direction."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:upright"
    std: float = Field(math.sqrt(0.2), gt=0)
    body: str | None = None
    reference: Reference = "gravity"
    span: float = Field(0.3, gt=0, description="m each way over which the terrain's slope "
                        "is taken")


PerJoint = Annotated[dict[str, Annotated[float, Field(gt=0)]], Field(min_length=1)]


class VariablePosture(CommandRef, RewardTerm):
    """exp(-mean over joints of ((q - default q) / std)^2), std per joint (rad) by the first
    pattern matching its name, from `std_standing` where the command's |lin xy| + |yaw rate| is
    below `walking_threshold`, `std_running` from `running_threshold` on, else `std_walking`:
    mjlab's `variable_posture`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:variable_posture"
    std_standing: PerJoint
    std_walking: PerJoint
    std_running: PerJoint
    walking_threshold: float = Field(0.05, ge=0)
    running_threshold: float = Field(1.5, ge=0)

    @model_validator(mode="after")
    def _patterns_and_order(self) -> VariablePosture:
        for field in ("std_standing", "std_walking", "std_running"):
            for pattern in getattr(self, field):
                try:
                    re.compile(pattern)
                except re.error as exc:
                    raise ValueError(f"{field} has '{pattern}', not a regular expression "
                                     f"({exc})") from None
        if self.walking_threshold > self.running_threshold:
            raise ValueError(f"walking_threshold ({self.walking_threshold:g}) is above "
                             f"running_threshold ({self.running_threshold:g})")
        return self


class BodyAngVelXYL2(RewardTerm):
    """The squared x and y (world frame) angular velocity of `body` ((rad/s)^2), from a MuJoCo
    frameangvel sensor: mjlab's `body_angular_velocity_penalty`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:body_angular_velocity_penalty"
    body: str


class AngularMomentumL2(RewardTerm):
    """The squared norm of the whole robot's angular momentum about its center of mass
    ((kg m^2/s)^2), from a MuJoCo subtreeangmom sensor on the root: mjlab's
    `angular_momentum_penalty` (its robot/root_angmom)."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:angular_momentum_penalty"


class SoftJointPosLimits(RewardTerm):
    """Over the actuated joints, how far each is outside its soft limits (rad or m): its range
    shrunk about its middle to `soft_factor` of it; unlimited joints never are. mjlab's
    `joint_pos_limits` with `soft_joint_pos_limit_factor`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:joint_pos_limits"
    soft_factor: float = Field(0.9, gt=0, le=1)


class CommandGated(CommandRef):
    """A term that is 0 wherever the command's |lin xy| + |yaw rate| is at or below
    `command_threshold`, as mjlab's foot terms."""

    command_threshold: float = Field(0.05, ge=0)


class FeetClearance(CommandGated, RewardTerm):
    """sum over the feet's sites of |height - target_height| x |site xy velocity| (m x m/s,
    world frame; height above the terrain: on flat ground, the site's z): mjlab's
    `feet_clearance`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:feet_clearance"
    sites: Sites
    target_height: float = Field(0.1, gt=0)


class FootContactTerm(CommandGated):
    """A term about the feet's contact with the terrain: the contacts of each named body's
    subtree with the world body's geoms, from MuJoCo contact sensors; a foot touches where any
    contact is found."""

    bodies: Bodies


class FeetSwingHeight(FootContactTerm, RewardTerm):
    """At each foot's first contact, (peak height / target_height - 1)^2, summed over the feet:
    the peak is its site's highest height above the terrain seen at a step's end while in the
    air, cleared at landing and at reset: mjlab's `feet_swing_height`. One site on each foot."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:feet_swing_height"
    sites: Sites
    target_height: float = Field(0.1, gt=0)


class FeetSlip(FootContactTerm, RewardTerm):
    """sum over the feet touching the terrain of |site xy velocity|^2 ((m/s)^2, world frame):
    mjlab's `feet_slip`. One site on each foot."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:feet_slip"
    sites: Sites


class SoftLanding(FootContactTerm, RewardTerm):
    """sum over the feet making their first contact of the net contact force's norm (N):
    mjlab's `soft_landing`."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:soft_landing"


class SelfCollisions(RewardTerm):
    """The number of contacts between bodies of `body`'s subtree (None: the root's, the whole
    robot) whose force exceeds `force_threshold` (N), at the env step's end, from a MuJoCo
    contact sensor reporting the `max_contacts` of largest force. mjlab's
    `self_collision_cost` counts instead the physics steps of the env step (its 4-step
    history) in which a self-contact's force exceeded it: lab sees the state once per step."""

    impl: ClassVar[str] = "labcli.envs.mdp.rewards:self_collision_cost"
    force_threshold: float = Field(10.0, ge=0)
    body: str | None = None
    max_contacts: int = Field(8, ge=1, le=64)


# terminations ----------------------------------------------------------------------------------
class TerminationTerm(Term):
    time_out: bool = Field(False, description="end the episode as a time-out (truncated, "
                           "bootstrapped), not as a failure")
    success: bool = Field(False, description="an episode it ends succeeded (a goal reached), "
                          "as well as those the task's success term judges at the time-out")

    @model_validator(mode="after")
    def _a_time_out_or_a_success(self) -> TerminationTerm:
        if self.time_out and self.success:
            raise ValueError("a termination is a time-out or a success, not both")
        return self


class TerrainOutOfBounds(TerminationTerm):
    """The base within `margin` of the terrain's outer edge (its grid and border): as mjlab's,
    a time-out. Needs env.terrain."""

    impl: ClassVar[str] = "labcli.envs.mdp.terminations:terrain_out_of_bounds"
    time_out: bool = True
    margin: float = Field(0.3, ge=0, description="m inside the edge")


class BaseHeightBelow(TerminationTerm):
    """The root below `minimum_height` (m) above the ground under it."""

    impl: ClassVar[str] = "labcli.envs.mdp.terminations:root_height_below_minimum"
    minimum_height: float


class BadOrientation(TerminationTerm):
    """The root tilted more than `limit_angle` (rad) from upright."""

    impl: ClassVar[str] = "labcli.envs.mdp.terminations:bad_orientation"
    limit_angle: float = Field(gt=0)


class IllegalContact(Contacts, TerminationTerm):
    """Any of the named bodies in contact (its net contact force above `threshold`, N). With
    `against`, only its contacts with that body's geoms count (`world`: the ground), and each
    named body's subtree's (a hand with its fingers): mjlab's `illegal_contact` on an
    end effector's subtree against the terrain."""

    impl: ClassVar[str] = "labcli.envs.mdp.terminations:illegal_contact"
    against: str | None = Field(None, min_length=1, description="a body: contacts with its "
                                "geoms only; None: with anything")


# events ----------------------------------------------------------------------------------------
class EventTerm(RangeChecked):
    pass


class ResetJointsByOffset(EventTerm):
    """At reset, each joint's default position and velocity plus a uniform draw from these
    ranges, positions clamped to the joint's limits."""

    impl: ClassVar[str] = "labcli.envs.mdp.events:reset_joints_by_offset"
    position_range: Range = (0.0, 0.0)
    velocity_range: Range = (0.0, 0.0)


class ResetJointsByScale(EventTerm):
    """At reset, each joint's default position times a uniform draw from `position_range`,
    clamped to the joint's limits (Isaac Lab's `reset_joints_by_scale`). `velocity_range` is
    Isaac Lab's key: the default velocities are 0, which any scale leaves 0."""

    impl: ClassVar[str] = "labcli.envs.mdp.events:reset_joints_by_scale"
    position_range: Range = (1.0, 1.0)
    velocity_range: Range = (1.0, 1.0)


POSE_KEYS = ("x", "y", "z", "roll", "pitch", "yaw")


def check_pose_keys(field: str, ranges: dict[str, Range]) -> None:
    unknown = set(ranges) - set(POSE_KEYS)
    if unknown:
        raise ValueError(f"{field} has {sorted(unknown)}; its keys are {', '.join(POSE_KEYS)}")


class ResetRootUniform(EventTerm):
    """At reset, the root's (or with `body`, a free body's) default pose plus uniform offsets
    per key of `pose_range` (x, y, z in m; roll, pitch, yaw in rad), and velocities drawn from
    `velocity_range` (x, y, z in m/s; roll, pitch, yaw in rad/s, world frame). Keys left out
    stay at 0."""

    impl: ClassVar[str] = "labcli.envs.mdp.events:reset_root_state_uniform"
    body: str | None = Field(None, min_length=1, description="a free body (an object) to "
                             "reset instead of the robot's root")
    pose_range: dict[str, Range] = Field(default_factory=dict)
    velocity_range: dict[str, Range] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _known_keys(self) -> ResetRootUniform:
        for field in ("pose_range", "velocity_range"):
            check_pose_keys(field, getattr(self, field))
        return self


class PushByVelocity(EventTerm):
    """Every `interval_s` (drawn per env from the range), the root's velocity is changed by a
    uniform draw from `velocity_range` (keys as ResetRootUniform's): Isaac Lab's
    `push_by_setting_velocity`, as an interval event."""

    impl: ClassVar[str] = "labcli.envs.mdp.events:push_by_setting_velocity"
    interval_s: Range = (10.0, 15.0)
    velocity_range: dict[str, Range] = Field(default_factory=dict)


class ModelEvent(EventTerm):
    """A per-env change of the physics (MuJoCo's per-env models on the cpu backend, batched
    model fields on warp), drawn once at start-up or again at every reset of the env."""

    mode: Literal["startup", "reset"] = "startup"
    bodies: Bodies = Field(default_factory=lambda: [".*"],
                              description="bodies whose geoms or mass it changes (patterns)")


class RandomizeFriction(ModelEvent):
    """Each named body's geoms' sliding friction, drawn per env and geom from `friction_range`
    (MuJoCo combines two geoms' friction by their maximum): Isaac Lab's
    `randomize_rigid_body_material` for MuJoCo's single coefficient."""

    impl: ClassVar[str] = "labcli.envs.mdp.events:randomize_rigid_body_friction"
    friction_range: Range = (0.8, 0.8)


class RandomizeMass(ModelEvent):
    """Each named body's mass plus a draw from `mass_range` (kg) per env: Isaac Lab's
    `randomize_rigid_body_mass` with operation "add"."""

    impl: ClassVar[str] = "labcli.envs.mdp.events:randomize_rigid_body_mass"
    mass_range: Range = (0.0, 0.0)


class RandomizeCom(ModelEvent):
    """Each named body's center of mass moved by a draw per axis from `com_range` (m, keys x,
    y, z; keys left out stay), per env: Isaac Lab's `randomize_rigid_body_com`."""

    impl: ClassVar[str] = "labcli.envs.mdp.events:randomize_rigid_body_com"
    com_range: dict[str, Range] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _known_axes(self) -> RandomizeCom:
        unknown = set(self.com_range) - {"x", "y", "z"}
        if unknown:
            raise ValueError(f"com_range has {sorted(unknown)}; its keys are x, y, z")
        return self


class JointModelEvent(EventTerm):
    """A per-env change of each named joint's own value (hinge and slide joints; the free
    joint is never one), drawn per joint from `range`: `scale` multiplies the model's value,
    `add` adds to it, `abs` replaces it (Isaac Lab's operations), at start-up or every reset."""

    mode: Literal["startup", "reset"] = "startup"
    joints: list[str] = Field(default_factory=lambda: [".*"], min_length=1,
                              description="joints whose value it changes (patterns)")
    range: Range = (1.0, 1.0)
    operation: Literal["scale", "add", "abs"] = "scale"


class RandomizeJointFriction(JointModelEvent):
    """MuJoCo's dry friction of each joint (`dof_frictionloss`, N m): Isaac Lab's
    `randomize_joint_parameters` for friction."""

    impl: ClassVar[str] = "labcli.envs.mdp.events:randomize_joint_friction"


class RandomizeJointDamping(JointModelEvent):
    """Each joint's passive viscous damping (`dof_damping`, N m s/rad)."""

    impl: ClassVar[str] = "labcli.envs.mdp.events:randomize_joint_damping"


class RandomizeJointArmature(JointModelEvent):
    """Each joint's armature (`dof_armature`, the rotor's reflected inertia, kg m^2): Isaac
    Lab's `randomize_joint_parameters` for armature."""

    impl: ClassVar[str] = "labcli.envs.mdp.events:randomize_joint_armature"


class EncoderBias(EventTerm):
    """A constant offset b per actuated joint and env, drawn from `bias_range` (rad, m for a
    slide joint) at start-up or every reset: encoders that read q + b. Joint positions observed
    with `JointPos(biased=True)` read it, and position targets are taken back by it (the servo
    aims for target - b, where its encoder reads the target): mjlab's `encoder_bias`."""

    impl: ClassVar[str] = "labcli.envs.mdp.events:encoder_bias"
    mode: Literal["startup", "reset"] = "startup"
    joints: list[str] = Field(default_factory=lambda: [".*"], min_length=1,
                              description="actuated joints it offsets (patterns)")
    bias_range: Range = (0.0, 0.0)


class RandomizeActuatorGains(EventTerm):
    """Each named position servo's stiffness (kp) and damping (kd), scaled per env and
    actuator by draws from `stiffness_range` and `damping_range`: Isaac Lab's
    `randomize_actuator_gains` with operation "scale", for MuJoCo's position actuators and the
    PD law of a robot description's `ideal_pd` and `dc_motor` groups."""

    impl: ClassVar[str] = "labcli.envs.mdp.events:randomize_actuator_gains"
    mode: Literal["startup", "reset"] = "startup"
    actuators: list[str] = Field(default_factory=lambda: [".*"], min_length=1,
                                 description="actuators whose PD gains it scales")
    stiffness_range: Range = (1.0, 1.0)
    damping_range: Range = (1.0, 1.0)


# actions ---------------------------------------------------------------------------------------
class ActionTerm(Term):
    """How actions in [-1, 1] become controls: `scale` for every actuator, or per actuator by
    regular expressions on their names (the first that matches wins), or None: each joint's
    from the task's robot description (env.robot).

    `delay`: the motors' latency, (low, high) physics steps, drawn per env at every episode's
    start (Isaac Lab's `DelayedPDActuator`, mjlab's delayed actuators): a control reaches the
    motors that many physics steps after the policy sent it, the one before it held until then.
    None: no latency."""

    scale: float | dict[str, float] | None = 1.0
    delay: tuple[int, int] | None = None

    @model_validator(mode="after")
    def _delay_ordered(self) -> ActionTerm:
        if self.delay is not None:
            low, high = self.delay
            if low < 0 or low > high:
                raise ValueError(f"delay is ({low}, {high}) physics steps: give (low, high) "
                                 "with 0 <= low <= high")
        return self


class JointEffort(ActionTerm):
    """ctrl = scale x action: with MuJoCo motor actuators (gear g), a joint torque of g x ctrl."""

    impl: ClassVar[str] = "labcli.envs.mdp.actions:JointEffortAction"


class BinaryJoints(BaseModel):
    """Actuators driven to one of two targets (a gripper's fingers): `open` where the action
    is 0 or more, `close` where it is negative (Isaac Lab's `BinaryJointPositionAction`)."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)
    actuators: list[str] = Field(min_length=1, description="actuators' names or patterns")
    open: float = Field(description="the target where the action is >= 0")
    close: float = Field(description="the target where the action is < 0")


class JointPosition(ActionTerm):
    """ctrl = default joint position + scale x action: targets for MuJoCo position actuators,
    whose kp, kv and force limits integrate the PD inside every physics substep. `binary`:
    actuators opened or closed instead (a gripper)."""

    impl: ClassVar[str] = "labcli.envs.mdp.actions:JointPositionAction"
    binary: BinaryJoints | None = None


# curriculum -----------------------------------------------------------------------------------
class CurriculumTerm(Term):
    pass


class RewardWeight(CurriculumTerm):
    """The reward term `term`'s weight becomes `weight` once the env has stepped `num_steps`
    times since it was made (a resumed run counts on): Isaac Lab's `modify_reward_weight`, by
    its common step counter."""

    impl: ClassVar[str] = "labcli.envs.mdp.curriculum:modify_reward_weight"
    term: str = Field(min_length=1, description="a reward term's name in env.rewards")
    weight: float
    num_steps: int = Field(ge=0, description="env steps (each a step of every env)")
    then: list[tuple[int, float]] = Field(default_factory=list, description="later stages: "
                                          "(num_steps, weight) pairs, each weight from its "
                                          "step count on (mjlab's `reward_curriculum`)")

    @model_validator(mode="after")
    def _stages_in_order(self) -> RewardWeight:
        counts = [self.num_steps] + [count for count, _ in self.then]
        if counts != sorted(counts):
            raise ValueError(f"the stages start at {counts} env steps: give them in order")
        return self


# success --------------------------------------------------------------------------------------
class MovedTowardTarget(Target):
    """An episode that reached its time-out having moved `distance` m or more toward the target
    (horizontally, from where it started) succeeded."""

    impl: ClassVar[str] = "labcli.envs.mdp.success:moved_toward_target"
    distance: float = Field(gt=0)


class TrackedCommand(CommandRef):
    """An episode that reached its time-out tracking the named velocity command with a mean
    error under `lin_vel_error` (m/s, xy) and `ang_vel_error` (rad/s, yaw rate) succeeded."""

    impl: ClassVar[str] = "labcli.envs.mdp.success:tracked_command"
    lin_vel_error: float = Field(0.25, gt=0)
    ang_vel_error: float = Field(0.3, gt=0)


class PoseReached(PoseCommandRef):
    """An episode that reached its time-out with the commanded site within `position_error`
    (m) of its target position and, unless None, `orientation_error` (rad) of its
    orientation succeeded."""

    impl: ClassVar[str] = "labcli.envs.mdp.success:pose_reached"
    position_error: float = Field(0.05, gt=0)
    orientation_error: float | None = Field(None, gt=0)


# objects -------------------------------------------------------------------------------------
class Box(BaseModel):
    """A box with a free joint that the task adds to its model (a cube for an arm to lift), at
    `pos` in the world, resting there at reset unless an event moves it. Its contacts are
    MuJoCo's defaults, or the robot's geoms' of higher priority (a gripper's pads)."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)

    size: tuple[float, float, float] = Field(description="half-lengths along x, y, z (m)")
    mass: float = Field(gt=0, description="kg")
    pos: tuple[float, float, float] = Field(description="where it starts, world frame (m)")
    rgba: tuple[float, float, float, float] = (0.8, 0.2, 0.2, 1.0)

    @model_validator(mode="after")
    def _positive_size(self) -> Box:
        if min(self.size) <= 0:
            raise ValueError(f"size is {self.size}: half-lengths are positive (m)")
        return self


# the task ---------------------------------------------------------------------------------------
class Group(BaseModel):
    """A group of terms: each field one term, None to leave it out."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    def terms(self) -> list[tuple[str, Term]]:
        return [(name, term) for name, term in self if term is not None]


class MotorEvents(Group):
    """The randomization of a robot's joints and motors that sim-to-real recipes add, each off
    until set (`--set env.events.actuator_gains.stiffness_range=[0.8,1.2]`): a task's events
    group inherits it."""

    joint_friction: RandomizeJointFriction | None = None
    joint_damping: RandomizeJointDamping | None = None
    joint_armature: RandomizeJointArmature | None = None
    actuator_gains: RandomizeActuatorGains | None = None


class RobotTaskConfig(TaskConfig):
    """The settings of a task built from terms (`labcli.envs.mdp.task.RobotTask`). A subclass
    sets its groups' models and defaults; weights live with their rewards, not in
    `reward_weights`."""

    play_overrides: ClassVar[dict[str, Any]] = {"observation_noise": False}
    # What play may ask of a trained policy: a latency, and what its commands ask (a command
    # term's settings, e.g. its ranges; not the term itself, which the policy observes).
    play_settable: ClassVar[frozenset[str]] = frozenset({"actions.delay",
                                                         "observations.*.delay",
                                                         "commands.*.*"})

    robot: RobotDescription | None = Field(None, description="the robot's motors, gains and "
                                           "parts, written into the model; None: the MJCF's own")
    root_body: str | None = Field(None, description="the floating base (a body with a free "
                                  "joint); None: the first such, if any (a planar or fixed "
                                  "base has none)")
    default_pose: str | None = Field("home", description="the model's keyframe that resets "
                                     "start from (Isaac Lab's init_state); None: qpos0")
    terrain: TerrainConfig | None = Field(None, description="a grid of terrain patches in "
                                          "place of the model's ground plane, robots starting "
                                          "on them; None: the model's own ground")
    objects: dict[str, Box] = Field(default_factory=dict, description="free bodies the task "
                                    "adds to the model, by body name (a cube to lift)")
    # Concrete types: a run's params/env.yaml is read back into them. A subclass declares its own
    # (e.g. `actions: JointPosition = JointPosition(scale=0.25)`).
    actions: JointEffort = JointEffort()
    commands: Group = Group()
    observations: Group = Group()
    rewards: Group = Group()
    terminations: Group = Group()
    events: Group = Group()
    curriculum: Group = Group()
    observation_noise: bool = Field(True, description="add each observation term's noise "
                                    "(training; lab play sets it false unless asked)")
    critic_observations: CriticInput = Field(
        "policy", description="what an actor-critic learner's critic reads: the policy's "
        "observations; noise_free, the same terms without their noise, bias and delay (the "
        "critic group of mjlab and Isaac Lab, corruption off); privileged, those and then "
        "env.critic_extras, terms only the critic reads (a framework without a critic input of "
        "its own trains its critic on the policy's, and says so)")
    # Concrete in a subclass too, as the other groups.
    critic_extras: Group = Field(Group(), description="observation terms only the critic "
                                 "reads, without noise, after the policy's (with "
                                 "critic_observations: privileged)")
    success: Term | None = None
    rewards_per_second: bool = Field(False, description="weights are per second of the "
                                     "episode: times the env step's duration in each step "
                                     "(Isaac Lab's reward manager)")
    reward_weights: dict[str, float] = Field(default_factory=dict, exclude=True)

    @model_validator(mode="after")
    def _extras_are_privileged(self) -> RobotTaskConfig:
        if self.critic_observations == "privileged" and not self.critic_extras.terms():
            raise ValueError("critic_observations is privileged and env.critic_extras lists no "
                             "term: give one, or use noise_free")
        return self

    @model_validator(mode="after")
    def _weights_live_with_rewards(self) -> RobotTaskConfig:
        if self.reward_weights:
            raise ValueError("a robot task's reward weights are env.rewards.<term>.weight, "
                             "not env.reward_weights")
        if type(self).model_fields["rewards"].default.terms() and not self.rewards.terms():
            raise ValueError("every reward term is left out (null): keep at least one, or "
                             "give one a weight of 0")
        return self

    def weights(self, step_dt: float) -> dict[str, float]:
        per_step = step_dt if self.rewards_per_second else 1.0
        return {name: term.weight * per_step for name, term in self.rewards.terms()}
