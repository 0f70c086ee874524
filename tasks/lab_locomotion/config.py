"""Ant and Humanoid as Isaac Lab's `Isaac-Ant-v0` / `Isaac-Humanoid-v0` define them: run
toward a target 1 km ahead; observations, reward terms and weights, resets and terminations as
theirs (classic/{ant,humanoid}/*_env_cfg.py). Set any of it with `--set env.<group>.<term>...`."""

from __future__ import annotations

from pydantic import Field

from labcli.envs.mdp import config as c

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
