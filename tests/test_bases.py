"""Robots whose base is not a free joint, built from the documented building blocks: a planar
hopper (Gymnasium's Hopper's slide x, slide z and hinge y root joints) and a fixed two-link arm
train on their joints' terms, a term that needs a floating base is one line naming it, and a
robot description's `base` agrees with its model."""

from __future__ import annotations

from typing import ClassVar

import mujoco
import pytest
import torch

from labcli.envs.env import LabVecEnv
from labcli.envs.mdp import config as c
from labcli.envs.mdp import robot_model
from labcli.envs.mdp.description import Actuators, RobotDescription
from labcli.envs.mdp.task import RobotTask
from labcli.envs.spec import TaskSpec
from labcli.errors import LabError

HOPPER = """
<mujoco model="planar_hopper">
  <option timestep="0.005"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 .1"/>
    <body name="torso" pos="0 0 1.05">
      <joint name="rootx" type="slide" axis="1 0 0"/>
      <joint name="rootz" type="slide" axis="0 0 1"/>
      <joint name="rooty" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0.2 0 0 -0.2" size="0.05" mass="3"/>
      <body name="thigh" pos="0 0 -0.2">
        <joint name="hip" type="hinge" axis="0 -1 0" range="-1.5 0.2"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.4" size="0.04"/>
        <body name="leg" pos="0 0 -0.4">
          <joint name="knee" type="hinge" axis="0 -1 0" range="-1.5 0"/>
          <geom type="capsule" fromto="0 0 0 0 0 -0.4" size="0.03"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="hip" gear="100" ctrlrange="-1 1"/>
    <motor joint="knee" gear="100" ctrlrange="-1 1"/>
  </actuator>
</mujoco>
"""

ARM = """
<mujoco model="two_link_arm">
  <option timestep="0.01" gravity="0 0 -9.81"/>
  <worldbody>
    <body name="base" pos="0 0 0.5">
      <geom type="cylinder" size="0.05 0.05"/>
      <body name="upper" pos="0 0 0.05">
        <joint name="shoulder" type="hinge" axis="0 1 0" range="-2 2" damping="1"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
        <body name="fore" pos="0.3 0 0">
          <joint name="elbow" type="hinge" axis="0 1 0" range="-2 2" damping="1"/>
          <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.025"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position joint="shoulder" kp="50" kv="5"/>
    <position joint="elbow" kp="50" kv="5"/>
  </actuator>
</mujoco>
"""


def forward_velocity(task, cfg):
    """A planar base's forward speed, written for it as docs/plugins.md says: the root slide's
    velocity, from the sim's qvel."""
    return task.sim.qvel[:, task.model.joint("rootx").dofadr[0]]


class ForwardVelocity(c.RewardTerm):
    impl: ClassVar[str] = "test_bases:forward_velocity"


class _Observations(c.Group):
    joint_pos: c.JointPos | None = c.JointPos()
    joint_vel: c.JointVel | None = c.JointVel()
    actions: c.LastAction | None = c.LastAction()


class _Rewards(c.Group):
    forward: ForwardVelocity | None = ForwardVelocity(weight=1.0)
    action_l2: c.ActionL2 | None = c.ActionL2(weight=-0.01)
    action_rate_l2: c.ActionRateL2 | None = c.ActionRateL2(weight=-0.01)


class _Events(c.Group):
    reset_robot_joints: c.ResetJointsByOffset | None = c.ResetJointsByOffset(
        position_range=(-0.1, 0.1), velocity_range=(-0.1, 0.1))


class _Joints(c.RobotTaskConfig):
    num_envs: int = 4
    decimation: int = 4
    episode_length_s: float = 1.0
    default_pose: str | None = None
    actions: c.JointEffort = c.JointEffort(scale=1.0)
    observations: _Observations = _Observations()
    rewards: _Rewards = _Rewards()
    events: _Events = _Events()


class _ArmRewards(c.Group):
    action_l2: c.ActionL2 | None = c.ActionL2(weight=-0.01)


class _Arm(_Joints):
    actions: c.JointPosition = c.JointPosition(scale=0.5)
    rewards: _ArmRewards = _ArmRewards()


def make(tmp_path, xml: str, config: type, **settings) -> LabVecEnv:
    path = tmp_path / "model.xml"
    path.write_text(xml)
    spec = TaskSpec(name="base", task=RobotTask, config=config, model=path)
    env = LabVecEnv(spec, config(**settings))
    env.reset(seed=0)
    return env


@pytest.mark.parametrize(("xml", "config"), [(HOPPER, _Joints), (ARM, _Arm)],
                         ids=["planar", "fixed"])
def test_a_planar_or_fixed_base_steps_on_its_joints_terms(tmp_path, xml, config):
    env = make(tmp_path, xml, config)
    try:
        assert not env.task.robot.floating
        assert env.task.robot.joint_names == (["hip", "knee"] if xml is HOPPER
                                              else ["shoulder", "elbow"])
        for _ in range(60):  # across the 1 s episodes' ends and resets
            obs, reward, terminated, truncated, _ = env.step(torch.rand(4, 2) * 2 - 1)
            assert obs.shape == (4, 6) and torch.isfinite(obs).all()
            assert torch.isfinite(reward).all()
        assert truncated.dtype == torch.bool
        if xml is HOPPER:  # the torso's slide: the reward's forward term moved with it
            forward = env.task._rewards[0].compute()
            assert torch.equal(forward, env.sim.qvel[:, 0])
    finally:
        env.close()


class _WithFloating(_Observations):
    base_lin_vel: c.BaseLinVel | None = None


class _WithUpright(_Rewards):
    upright: c.UprightExp | None = None


class _WithTerms(_Joints):
    observations: _WithFloating = _WithFloating()
    rewards: _WithUpright = _WithUpright()


@pytest.mark.parametrize("settings", [
    {"observations": _WithFloating(base_lin_vel=c.BaseLinVel())},
    {"rewards": _WithUpright(upright=c.UprightExp(weight=1.0))},
], ids=["base_lin_vel", "upright"])
def test_a_term_that_needs_a_floating_base_says_so_in_one_line(tmp_path, settings):
    with pytest.raises(LabError) as err:
        make(tmp_path, HOPPER, _WithTerms, **settings)
    message = str(err.value)
    assert "\n" not in message and "needs a floating base" in message, message
    assert "model 'planar_hopper' has none" in message, message


def arm_description(base: str) -> RobotDescription:
    return RobotDescription(base=base, actuators={"arm": Actuators(
        joints=["shoulder", "elbow"], effort_limit=20.0, armature=0.01, stiffness=50.0,
        damping=5.0)})


def test_a_fixed_arm_s_description_says_so_and_is_written_into_its_model(tmp_path):
    env = make(tmp_path, ARM, _Arm, robot=arm_description("fixed"))
    try:
        assert not env.task.robot.floating
        assert env.sim.model.actuator_forcerange[:, 1].tolist() == [20.0, 20.0]
        env.step(torch.zeros(4, 2))
    finally:
        env.close()


@pytest.mark.parametrize(("xml", "base", "said"), [
    (ARM, "floating", "env.robot.base is 'floating', but model 'two_link_arm' has no free joint"),
    (HOPPER, "floating", "model 'planar_hopper' has no free joint"),
], ids=["arm", "hopper"])
def test_a_floating_description_of_a_model_without_a_free_joint_is_one_line(
        tmp_path, xml, base, said):
    config = _Arm if xml is ARM else _Joints
    description = arm_description(base) if xml is ARM else RobotDescription(
        base=base, actuators={"legs": Actuators(joints=["hip", "knee"], effort_limit=100.0,
                                                armature=0.01, action_scale=1.0)})
    with pytest.raises(LabError) as err:
        make(tmp_path, xml, config, robot=description)
    assert said in err.value.message and "\n" not in err.value.message
    assert "env.robot.base=fixed" in err.value.hint


def test_a_fixed_description_of_a_floating_robot_is_one_line():
    spec = mujoco.MjSpec.from_string("""<mujoco model="box"><worldbody><body name="b">
        <freejoint name="root"/><geom size="0.1"/></body></worldbody></mujoco>""")
    with pytest.raises(LabError) as err:
        robot_model.apply(spec, arm_description("fixed"))
    assert err.value.message == ("env.robot.base is 'fixed', but model 'box' has a free joint "
                                 "('root'): its base floats")


@pytest.mark.parametrize(("xml", "tracked"), [(HOPPER, "torso"), (ARM, None)],
                         ids=["planar", "fixed"])
def test_a_video_follows_a_planar_robot_and_frames_a_fixed_one(xml, tracked):
    from labcli.envs.render.scene import _following

    model = mujoco.MjModel.from_xml_string(xml)
    camera = _following(model)
    if tracked is None:
        assert camera.type == mujoco.mjtCamera.mjCAMERA_FREE
    else:
        assert camera.type == mujoco.mjtCamera.mjCAMERA_TRACKING
        assert camera.trackbodyid == model.body(tracked).id
