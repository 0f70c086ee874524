"""The locomotion tasks' configs, as Isaac Lab defines them: Ant and Humanoid
(`Isaac-Ant-v0` / `Isaac-Humanoid-v0`: run toward a target 1 km ahead; classic/{ant,humanoid}/
*_env_cfg.py) and the Go1 on flat ground (`Isaac-Velocity-Flat-Unitree-Go1-v0`: track velocity
commands). Observations, reward terms and weights, resets and terminations as theirs; set any
of it with `--set env.<group>.<term>...`."""

from __future__ import annotations

import math
from typing import Any, ClassVar

from pydantic import Field

from lab_locomotion.g1 import ROBOT as G1
from lab_locomotion.go1 import ROBOT as GO1
from lab_locomotion.go2 import ROBOT as GO2
from labcli.envs.mdp import config as c
from labcli.envs.mdp import terrain as t
from labcli.envs.mdp.description import RobotDescription
from labcli.envs.mdp.terrain import TerrainConfig

# Isaac Lab: 120 Hz physics, decimation 2, 16 s episodes.
PHYSICS_DT = 1 / 120
EPISODE_S = 16.0


class LocomotionRewards(c.Group):
    progress: c.Progress | None = c.Progress(weight=1.0)
    alive: c.Alive | None = c.Alive(weight=0.5)
    upright: c.Upright | None = c.Upright(weight=0.1, threshold=0.93)
    move_to_target: c.MoveToTarget | None = c.MoveToTarget(weight=0.5, threshold=0.8)
    action_l2: c.ActionL2 | None = c.ActionL2(weight=-0.005)
    energy: c.Energy | None = c.Energy(weight=-0.05)
    joint_pos_limits: c.JointPosLimits | None = c.JointPosLimits(weight=-0.1, threshold=0.99)


class LocomotionEvents(c.Group):
    reset_base: c.ResetRootUniform | None = c.ResetRootUniform()
    reset_robot_joints: c.ResetJointsByOffset | None = c.ResetJointsByOffset(
        position_range=(-0.2, 0.2), velocity_range=(-0.1, 0.1))


class AntObservations(c.Group):
    base_height: c.BaseHeight | None = c.BaseHeight()
    base_lin_vel: c.BaseLinVel | None = c.BaseLinVel()
    base_ang_vel: c.BaseAngVel | None = c.BaseAngVel()
    base_yaw_roll: c.BaseYawRoll | None = c.BaseYawRoll()
    base_angle_to_target: c.AngleToTarget | None = c.AngleToTarget()
    base_up_proj: c.UpProj | None = c.UpProj()
    base_heading_proj: c.HeadingProj | None = c.HeadingProj()
    joint_pos_norm: c.JointPosNormalized | None = c.JointPosNormalized()
    joint_vel_rel: c.JointVel | None = c.JointVel(scale=0.2)
    feet_body_forces: c.BodyWrench | None = c.BodyWrench(
        scale=0.1, bodies=["front_left_foot", "front_right_foot", "left_back_foot",
                           "right_back_foot"])
    actions: c.LastAction | None = c.LastAction()


class AntTerminations(c.Group):
    torso_height: c.BaseHeightBelow | None = c.BaseHeightBelow(minimum_height=0.31)


class AntConfig(c.RobotTaskConfig):
    num_envs: int = Field(256, gt=0, le=2**20, description="parallel environments")
    episode_length_s: float = Field(EPISODE_S, gt=0, le=1e6, description="time-out, in seconds")
    nconmax: int | None = 15
    njmax: int | None = 38
    observations: AntObservations = AntObservations()
    rewards: LocomotionRewards = LocomotionRewards()
    terminations: AntTerminations = AntTerminations()
    events: LocomotionEvents = LocomotionEvents()
    success: c.MovedTowardTarget | None = c.MovedTowardTarget(distance=8.0)


class HumanoidObservations(AntObservations):
    base_ang_vel: c.BaseAngVel | None = c.BaseAngVel(scale=0.25)
    joint_vel_rel: c.JointVel | None = c.JointVel(scale=0.1)
    feet_body_forces: c.BodyWrench | None = c.BodyWrench(
        scale=0.01, bodies=["left_foot", "right_foot"])


class HumanoidRewards(LocomotionRewards):
    alive: c.Alive | None = c.Alive(weight=2.0)
    action_l2: c.ActionL2 | None = c.ActionL2(weight=-0.01)
    energy: c.Energy | None = c.Energy(weight=-0.005)
    joint_pos_limits: c.JointPosLimits | None = c.JointPosLimits(weight=-0.25, threshold=0.98)


class HumanoidTerminations(c.Group):
    torso_height: c.BaseHeightBelow | None = c.BaseHeightBelow(minimum_height=0.8)


class HumanoidConfig(AntConfig):
    default_pose: str | None = Field(None, description="the model's keyframe that resets start "
                                     "from; None: the MJCF's own pose")
    nconmax: int | None = 25
    njmax: int | None = 80
    observations: HumanoidObservations = HumanoidObservations()
    rewards: HumanoidRewards = HumanoidRewards()
    terminations: HumanoidTerminations = HumanoidTerminations()


# Velocity tracking on flat ground: Isaac Lab's Isaac-Velocity-Flat-Unitree-Go1-v0
# (locomotion/velocity/velocity_env_cfg.py with config/go1/{rough,flat}_env_cfg.py): 200 Hz
# physics, decimation 4, 20 s episodes.
class VelocityCommands(c.Group):
    base_velocity: c.UniformVelocityCommand | None = c.UniformVelocityCommand(
        resampling_time_range=(10.0, 10.0), rel_standing_envs=0.02, rel_heading_envs=1.0,
        heading_command=True, heading_control_stiffness=0.5)


class VelocityObservations(c.Group):
    base_lin_vel: c.BaseLinVel | None = c.BaseLinVel(noise=0.1)
    base_ang_vel: c.BaseAngVel | None = c.BaseAngVel(noise=0.2)
    projected_gravity: c.ProjectedGravity | None = c.ProjectedGravity(noise=0.05)
    velocity_commands: c.GeneratedCommands | None = c.GeneratedCommands()
    joint_pos: c.JointPos | None = c.JointPos(noise=0.01)
    joint_vel: c.JointVel | None = c.JointVel(noise=1.5)
    actions: c.LastAction | None = c.LastAction()


class Go1FlatRewards(c.Group):
    track_lin_vel_xy_exp: c.TrackLinVelXYExp | None = c.TrackLinVelXYExp(weight=1.5, std=0.5)
    track_ang_vel_z_exp: c.TrackAngVelZExp | None = c.TrackAngVelZExp(weight=0.75, std=0.5)
    lin_vel_z_l2: c.LinVelZL2 | None = c.LinVelZL2(weight=-2.0)
    ang_vel_xy_l2: c.AngVelXYL2 | None = c.AngVelXYL2(weight=-0.05)
    dof_torques_l2: c.JointTorquesL2 | None = c.JointTorquesL2(weight=-2e-4)
    dof_acc_l2: c.JointAccL2 | None = c.JointAccL2(weight=-2.5e-7)
    action_rate_l2: c.ActionRateL2 | None = c.ActionRateL2(weight=-0.01)
    # Menagerie's Go1 and Go2 have each foot as a sphere on its calf: the calves' contacts are
    # the feet's.
    feet_air_time: c.FeetAirTime | None = c.FeetAirTime(weight=0.25, bodies=[".*_calf"],
                                                          threshold_s=0.5)
    # Isaac Lab's Go1 leaves undesired (thigh) contacts out: --set it to turn it on.
    undesired_contacts: c.UndesiredContacts | None = None
    flat_orientation_l2: c.FlatOrientationL2 | None = c.FlatOrientationL2(weight=-2.5)


class Go1Terminations(c.Group):
    base_contact: c.IllegalContact | None = c.IllegalContact(bodies=["trunk"], threshold=1.0)


class Go1Events(c.MotorEvents):
    # Start-up: Isaac Lab's Go1 base-mass range (its velocity config has the term off for a
    # PhysX issue that MuJoCo does not share) and its center-of-mass shift.
    add_base_mass: c.RandomizeMass | None = c.RandomizeMass(bodies=["trunk"],
                                                            mass_range=(-1.0, 3.0))
    base_com: c.RandomizeCom | None = c.RandomizeCom(
        bodies=["trunk"], com_range={"x": (-0.05, 0.05), "y": (-0.05, 0.05), "z": (-0.01, 0.01)})
    reset_base: c.ResetRootUniform | None = c.ResetRootUniform(
        pose_range={"x": (-0.5, 0.5), "y": (-0.5, 0.5), "yaw": (-3.14, 3.14)},
        velocity_range={k: (-0.1, 0.1) for k in c.POSE_KEYS})
    reset_robot_joints: c.ResetJointsByScale | None = c.ResetJointsByScale(
        position_range=(0.5, 1.5), velocity_range=(0.0, 0.0))
    push_robot: c.PushByVelocity | None = c.PushByVelocity(
        interval_s=(10.0, 15.0), velocity_range={"x": (-0.1, 0.1), "y": (-0.1, 0.1)})


class Go1FlatConfig(c.RobotTaskConfig):
    # Isaac Lab's _PLAY config: no noise, no pushes.
    play_overrides: ClassVar[dict[str, Any]] = {**c.RobotTaskConfig.play_overrides,
                                                "events": {"push_robot": None}}
    robot: RobotDescription | None = GO1
    num_envs: int = Field(256, gt=0, le=2**20, description="parallel environments")
    episode_length_s: float = Field(20.0, gt=0, le=1e6, description="time-out, in seconds")
    decimation: int = Field(4, gt=0, le=1000, description="physics steps per env step")
    sim_dt: float | None = Field(0.005, gt=0, description="physics step")
    # mjlab's solver settings (Menagerie's scenes have MuJoCo's 100 and 50, or 5 and 8 in the
    # G1's scene_mjx).
    solver_iterations: int | None = Field(10, gt=0, le=1000)
    ls_iterations: int | None = Field(20, gt=0, le=1000)
    nconmax: int | None = 16
    njmax: int | None = 72
    actions: c.JointPosition = c.JointPosition(scale=0.25)
    # Isaac Lab's and mjlab's velocity tasks do not clip (Isaac Lab's rl_games configs: ±100):
    # their policies set targets several scales from the standing pose. Clipped to ±1, a
    # trained Go1 policy pressed 90% of its actions against the bound.
    clip_actions: float = 100.0
    commands: VelocityCommands = VelocityCommands()
    observations: VelocityObservations = VelocityObservations()
    rewards: Go1FlatRewards = Go1FlatRewards()
    terminations: Go1Terminations = Go1Terminations()
    events: Go1Events = Go1Events()
    success: c.TrackedCommand | None = c.TrackedCommand(lin_vel_error=0.25, ang_vel_error=0.3)
    # As Isaac Lab's velocity tasks: a return is the weighted terms' integral over the episode.
    rewards_per_second: bool = True


# Isaac Lab's Isaac-Velocity-Flat-Unitree-Go2-v0 (config/go2/{rough,flat}_env_cfg.py): go1-flat's
# recipe on the Go2, whose base body is `base`.
class Go2Terminations(c.Group):
    base_contact: c.IllegalContact | None = c.IllegalContact(bodies=["base"], threshold=1.0)


class Go2Events(Go1Events):
    add_base_mass: c.RandomizeMass | None = c.RandomizeMass(bodies=["base"],
                                                            mass_range=(-1.0, 3.0))
    base_com: c.RandomizeCom | None = c.RandomizeCom(
        bodies=["base"], com_range={"x": (-0.05, 0.05), "y": (-0.05, 0.05), "z": (-0.01, 0.01)})


class Go2FlatConfig(Go1FlatConfig):
    robot: RobotDescription | None = GO2
    terminations: Go2Terminations = Go2Terminations()
    events: Go2Events = Go2Events()


# The Unitree G1 on flat ground: mjlab's Mjlab-Velocity-Flat-Unitree-G1 (tasks/velocity/
# velocity_env_cfg.py with config/g1/env_cfgs.py): 200 Hz physics, decimation 4, 20 s episodes.
# The pelvis sways and turns with each step of a walking humanoid: success judges the velocity
# it keeps over a second (longer than a stride), not each step's.
class G1Commands(c.Group):
    base_velocity: c.UniformVelocityCommand | None = c.UniformVelocityCommand(
        resampling_time_range=(3.0, 8.0), rel_standing_envs=0.1, rel_heading_envs=0.3,
        rel_forward_envs=0.2, heading_command=True, heading_control_stiffness=0.5,
        lin_vel_x=(-1.0, 1.0), lin_vel_y=(-1.0, 1.0), ang_vel_z=(-0.5, 0.5), error_window=1.0)


class G1Observations(c.Group):
    base_lin_vel: c.BaseLinVel | None = c.BaseLinVel(noise=0.5)
    base_ang_vel: c.BaseAngVel | None = c.BaseAngVel(noise=0.2)
    projected_gravity: c.ProjectedGravity | None = c.ProjectedGravity(noise=0.05)
    joint_pos: c.JointPos | None = c.JointPos(noise=0.01, biased=True)
    joint_vel: c.JointVel | None = c.JointVel(noise=1.5)
    actions: c.LastAction | None = c.LastAction()
    velocity_commands: c.GeneratedCommands | None = c.GeneratedCommands()


FEET = ["left_ankle_roll_link", "right_ankle_roll_link"]
SOLES = ["left_foot", "right_foot"]
# mjlab's per-joint posture tolerances (rad), loosest where the gait needs motion: hips and
# knees, then ankle pitch; tight ankle roll and waist roll/pitch for balance.
STD_WALKING = {".*hip_pitch.*": 0.3, ".*hip_roll.*": 0.15, ".*hip_yaw.*": 0.15, ".*knee.*": 0.35,
               ".*ankle_pitch.*": 0.25, ".*ankle_roll.*": 0.1, ".*waist_yaw.*": 0.2,
               ".*waist_roll.*": 0.08, ".*waist_pitch.*": 0.1, ".*shoulder_pitch.*": 0.15,
               ".*shoulder_roll.*": 0.15, ".*shoulder_yaw.*": 0.1, ".*elbow.*": 0.15,
               ".*wrist.*": 0.3}
STD_RUNNING = {".*hip_pitch.*": 0.5, ".*hip_roll.*": 0.2, ".*hip_yaw.*": 0.2, ".*knee.*": 0.6,
               ".*ankle_pitch.*": 0.35, ".*ankle_roll.*": 0.15, ".*waist_yaw.*": 0.3,
               ".*waist_roll.*": 0.08, ".*waist_pitch.*": 0.2, ".*shoulder_pitch.*": 0.5,
               ".*shoulder_roll.*": 0.2, ".*shoulder_yaw.*": 0.15, ".*elbow.*": 0.35,
               ".*wrist.*": 0.3}


# The rest of mjlab's G1 critic group (velocity_env_cfg.py's critic_terms): each foot's height
# above the terrain, air time, contact and net contact force (sign(f) log(1 + |f|)), read with
# `critic_observations: privileged`.
class G1CriticExtras(c.Group):
    foot_height: c.FootHeight | None = c.FootHeight(bodies=FEET, sites=SOLES)
    foot_air_time: c.FootAirTime | None = c.FootAirTime(bodies=FEET)
    foot_contact: c.FootContact | None = c.FootContact(bodies=FEET)
    foot_contact_forces: c.FootContactForces | None = c.FootContactForces(bodies=FEET)


class G1Rewards(c.Group):
    track_linear_velocity: c.TrackLinearVelocity | None = c.TrackLinearVelocity(
        weight=2.0, std=0.5)
    track_angular_velocity: c.TrackAngularVelocity | None = c.TrackAngularVelocity(
        weight=2.0, std=math.sqrt(0.5))
    upright: c.UprightExp | None = c.UprightExp(weight=1.0, std=math.sqrt(0.2),
                                                 body="torso_link")
    pose: c.VariablePosture | None = c.VariablePosture(
        weight=1.0, std_standing={".*": 0.05}, std_walking=STD_WALKING,
        std_running=STD_RUNNING, walking_threshold=0.05, running_threshold=1.5)
    body_ang_vel: c.BodyAngVelXYL2 | None = c.BodyAngVelXYL2(weight=-0.05, body="torso_link")
    angular_momentum: c.AngularMomentumL2 | None = c.AngularMomentumL2(weight=-0.02)
    dof_pos_limits: c.SoftJointPosLimits | None = c.SoftJointPosLimits(weight=-1.0)
    action_rate_l2: c.ActionRateL2 | None = c.ActionRateL2(weight=-0.1)
    # mjlab's G1 sets its feet-air-time weight to 0: left out.
    foot_clearance: c.FeetClearance | None = c.FeetClearance(weight=-2.0, sites=SOLES,
                                                             target_height=0.1)
    foot_swing_height: c.FeetSwingHeight | None = c.FeetSwingHeight(
        weight=-0.25, bodies=FEET, sites=SOLES, target_height=0.1)
    foot_slip: c.FeetSlip | None = c.FeetSlip(weight=-0.1, bodies=FEET, sites=SOLES)
    soft_landing: c.SoftLanding | None = c.SoftLanding(weight=-1e-5, bodies=FEET)
    self_collisions: c.SelfCollisions | None = c.SelfCollisions(weight=-1.0,
                                                                force_threshold=10.0)


class G1Terminations(c.Group):
    fell_over: c.BadOrientation | None = c.BadOrientation(limit_angle=math.radians(70.0))


class G1Events(c.MotorEvents):
    foot_friction: c.RandomizeFriction | None = c.RandomizeFriction(bodies=FEET,
                                                                    friction_range=(0.3, 1.2))
    base_com: c.RandomizeCom | None = c.RandomizeCom(
        bodies=["torso_link"],
        com_range={"x": (-0.025, 0.025), "y": (-0.025, 0.025), "z": (-0.03, 0.03)})
    reset_base: c.ResetRootUniform | None = c.ResetRootUniform(
        pose_range={"x": (-0.5, 0.5), "y": (-0.5, 0.5), "z": (0.01, 0.05), "yaw": (-3.14, 3.14)})
    reset_robot_joints: c.ResetJointsByOffset | None = c.ResetJointsByOffset()
    push_robot: c.PushByVelocity | None = c.PushByVelocity(
        interval_s=(1.0, 3.0), velocity_range={
            "x": (-0.5, 0.5), "y": (-0.5, 0.5), "z": (-0.4, 0.4), "roll": (-0.52, 0.52),
            "pitch": (-0.52, 0.52), "yaw": (-0.78, 0.78)})
    # mjlab's encoder_bias draws up to 0.015 rad per joint; at 0 here, as the G1's figures were
    # measured: --set "env.events.encoder_bias.bias_range=[-0.015,0.015]" for mjlab's.
    encoder_bias: c.EncoderBias | None = c.EncoderBias(bias_range=(0.0, 0.0))


class G1FlatConfig(Go1FlatConfig):
    """go1-flat's episodes, decimation, unclipped actions, success and per-second rewards, with
    the G1's robot, physics and terms."""

    robot: RobotDescription | None = G1
    default_pose: str | None = "knees_bent"
    nconmax: int | None = 35
    njmax: int | None = 300
    actions: c.JointPosition = c.JointPosition(scale=None)
    commands: G1Commands = G1Commands()
    observations: G1Observations = G1Observations()
    rewards: G1Rewards = G1Rewards()
    terminations: G1Terminations = G1Terminations()
    events: G1Events = G1Events()
    # mjlab's critic group: the actor's terms without their noise. On one GPU it brought success
    # 0.9 from past 800 s of training to 390-420 s (three seeds; docs/benchmarks.md). mjlab's
    # critic reads the feet's terms besides: `privileged` adds them (not yet trained so).
    critic_observations: c.CriticInput = "noise_free"
    critic_extras: G1CriticExtras = G1CriticExtras()
    # Its yaw-rate commands ask 0.25 rad/s on average (±0.5): a G1 that never turned would pass
    # go1-flat's 0.3 rad/s bound. Half of it instead.
    success: c.TrackedCommand | None = c.TrackedCommand(lin_vel_error=0.25, ang_vel_error=0.15)


# Rough terrain: Isaac Lab's Isaac-Velocity-Rough-Unitree-Go1-v0 (locomotion/velocity/
# velocity_env_cfg.py, config/go1/rough_env_cfg.py; go1-flat is its flat variant). Isaac Lab's
# ROUGH_TERRAINS_CFG with the Go1's smaller boxes and roughness, its height scan, the terrain
# curriculum; its flat-orientation penalty off and a small feet-air-time reward.
def go1_terrain() -> TerrainConfig:
    stairs = {"step_height": (0.05, 0.23), "step_width": 0.3, "platform": 3.0}
    return TerrainConfig(types={
        "stairs": t.PyramidStairs(proportion=0.2, **stairs),
        "stairs_down": t.PyramidStairs(proportion=0.2, inverted=True, **stairs),
        # Isaac Lab's grid of 0.45 m boxes of random height, raised and sunk.
        "boxes": t.DiscreteObstacles(proportion=0.2, height=(0.025, 0.1), width=(0.45, 0.45),
                                     count=150),
        "rough": t.RandomRough(proportion=0.2, noise=(0.01, 0.06), step=0.01),
        "slope": t.PyramidSlope(proportion=0.1, slope=(0.0, 0.4)),
        "slope_down": t.PyramidSlope(proportion=0.1, slope=(0.0, 0.4), inverted=True),
    })


class Go1RoughObservations(VelocityObservations):
    height_scan: c.HeightScan | None = c.HeightScan()


class Go1RoughRewards(Go1FlatRewards):
    feet_air_time: c.FeetAirTime | None = c.FeetAirTime(weight=0.01, bodies=[".*_foot"],
                                                          threshold_s=0.5)
    flat_orientation_l2: c.FlatOrientationL2 | None = None


class Go1RoughTerminations(Go1Terminations):
    out_of_terrain_bounds: c.TerrainOutOfBounds | None = c.TerrainOutOfBounds()


# Isaac Lab's and mjlab's _PLAY rough configs: the curriculum off, so that each episode plays on
# a random level and type of the whole grid (and `--set env.terrain...` may pick them).
ROUGH_PLAY = {**Go1FlatConfig.play_overrides, "terrain": {"curriculum": False}}


class Go1RoughConfig(Go1FlatConfig):
    play_overrides: ClassVar[dict[str, Any]] = ROUGH_PLAY
    # go1-rough's Go1 is go1_datasheet.py's MJCF, with its own motors: its recipe was measured
    # on it (docs/benchmarks.md), not yet on Menagerie's.
    robot: RobotDescription | None = None
    terrain: TerrainConfig | None = Field(default_factory=go1_terrain)
    # Height fields and stair edges touch a foot at more points than a plane.
    nconmax: int | None = 40
    njmax: int | None = 160
    observations: Go1RoughObservations = Go1RoughObservations()
    rewards: Go1RoughRewards = Go1RoughRewards()
    terminations: Go1RoughTerminations = Go1RoughTerminations()


# mjlab's Mjlab-Velocity-Rough-Unitree-G1 (g1-flat is its flat variant): its ROUGH_TERRAINS_CFG
# (t.rough()) with the curriculum, and the pelvis's height scan in the observations, as
# mjlab's: heights above the terrain scaled by 1 / 5 m, no offset, no clip.
class G1RoughObservations(G1Observations):
    height_scan: c.HeightScan | None = c.HeightScan(offset=0.0, scale=0.2, clip=None)


class G1RoughTerminations(G1Terminations):
    out_of_terrain_bounds: c.TerrainOutOfBounds | None = c.TerrainOutOfBounds()


class G1RoughConfig(G1FlatConfig):
    play_overrides: ClassVar[dict[str, Any]] = ROUGH_PLAY
    terrain: TerrainConfig | None = Field(default_factory=t.rough)
    # mjlab's rough room (g1-flat's 300 rows overflowed in 1.2% of the env steps of a GPU run's
    # first 226 iterations, each such env reset).
    nconmax: int | None = 70
    njmax: int | None = 1500
    observations: G1RoughObservations = G1RoughObservations()
    terminations: G1RoughTerminations = G1RoughTerminations()
