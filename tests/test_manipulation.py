"""Arms: panda-reach on Menagerie's Franka Panda, its pose command against MuJoCo's own
kinematics, the reaching rewards and success against hand-computed cases, and the robot
description's home pose."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch
from conftest import needs_menagerie
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.envs.env import LabVecEnv
from labcli.envs.mdp import config as c
from labcli.envs.mdp import robot_model
from labcli.envs.mdp.description import Actuators, RobotDescription
from labcli.envs.mdp.task import RobotTask
from labcli.envs.spec import TaskSpec
from labcli.errors import LabError
from labcli.gym import make_env

pytestmark = needs_menagerie("franka_emika_panda")
QUIET = ["env.observation_noise=false"]


def reach(n: int, *overrides: str):
    env = make_env("panda-reach", num_envs=n, seed=0, overrides=[*QUIET, *overrides],
                   backend="cpu", device="cpu")
    env.reset()
    return env


def mujoco_site_pose(env, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Env i's gripper site in the world (link0's frame: the arm stands at the origin), from
    MuJoCo's kinematics of its qpos."""
    model = env.sim.model
    data = mujoco.MjData(model)
    data.qpos[:] = env.sim.qpos[i].double().numpy()
    mujoco.mj_kinematics(model, data)
    site = model.site("gripper").id
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[site])
    return data.site_xpos[site].copy(), quat


def test_the_home_pose_is_isaac_lab_s_and_the_hand_starts_open():
    env = reach(2, "env.events.reset_robot_joints=null")
    try:
        names = env.task.robot.joint_names
        home = dict(zip(names, env.task.robot.default_joint_pos[0].tolist(), strict=True))
        assert home == pytest.approx({"joint1": 0.0, "joint2": -0.569, "joint3": 0.0,
                                      "joint4": -2.810, "joint5": 0.0, "joint6": 3.037,
                                      "joint7": 0.741, "finger_joint1": 0.04})
        assert torch.allclose(env.task.robot.joint_pos, env.task.robot.default_joint_pos)
        assert env.sim.model.actuator_forcerange[:, 1].tolist() == [87.0] * 4 + [12.0] * 3 + [200.0]
    finally:
        env.close()


@pytest.mark.parametrize(("compensated", "sag"), [(True, 1e-6), (False, 0.01)])
def test_the_arm_s_weight_is_compensated_as_franka_s_controller_does(compensated, sag):
    """Held at home for 2 s: with compensation no joint sags; without, the servos give way
    under the arm's weight (Menagerie's gains: kp 1000 at the shoulder)."""
    env = reach(2, "env.events.reset_robot_joints=null",
                f"env.robot.gravity_compensation={str(compensated).lower()}")
    try:
        for _ in range(60):
            env.step(torch.zeros(2, 8))
        robot = env.task.robot
        moved = float((robot.joint_pos - robot.default_joint_pos).abs().max())
        assert (moved < sag) if compensated else (moved > sag)
        weightless = env.sim.model.body_gravcomp[1:].tolist()  # link0 to the fingers
        assert weightless == ([1.0] * 11 if compensated else [0.0] * 11)
    finally:
        env.close()


def test_the_pose_command_is_drawn_in_its_box_pointing_down():
    env = reach(64)
    try:
        command = env.task.command("ee_pose").command
        pos, quat = command[:, :3], command[:, 3:]
        assert ((pos[:, 0] >= 0.35) & (pos[:, 0] <= 0.65)).all()
        assert ((pos[:, 1] >= -0.2) & (pos[:, 1] <= 0.2)).all()
        assert ((pos[:, 2] >= 0.15) & (pos[:, 2] <= 0.5)).all()
        assert torch.allclose(quat.norm(dim=1), torch.ones(64, dtype=quat.dtype))
        for q in quat[:4].double().numpy():  # pitch pi: the hand's z axis points down
            mat = np.empty(9)
            mujoco.mju_quat2Mat(mat, q)
            assert mat.reshape(3, 3)[:, 2] == pytest.approx([0.0, 0.0, -1.0], abs=1e-6)
    finally:
        env.close()


def test_the_errors_are_mujoco_s_site_pose_against_the_command():
    # The arm held at rest: frame sensors report the state of the physics step's start.
    env = reach(4)
    try:
        for _ in range(60):
            env.step(torch.zeros(4, 8))
        made = env.task.command("ee_pose")
        site_pos, site_quat = mujoco_site_pose(env, 2)
        pos, quat = made.site_pose()
        assert pos[2].double().numpy() == pytest.approx(site_pos, abs=1e-4)
        assert abs(float((quat[2].double() * torch.from_numpy(site_quat)).sum())) == (
            pytest.approx(1.0, abs=1e-6))
        # A target 3 cm above the site, turned 0.4 rad about its own z: errors 0.03 m and 0.4.
        turn = np.array([math.cos(0.2), 0.0, 0.0, math.sin(0.2)])
        target_quat = np.empty(4)
        mujoco.mju_mulQuat(target_quat, site_quat, turn)
        made.command[2, :3] = torch.from_numpy(site_pos + [0.0, 0.0, 0.03])
        made.command[2, 3:] = torch.from_numpy(target_quat)
        env.task.robot.forget_derived()
        assert float(made.position_error()[2]) == pytest.approx(0.03, abs=1e-5)
        assert float(made.orientation_error()[2]) == pytest.approx(0.4, abs=1e-4)
        rewards = {b.name: b.compute() for b in env.task._rewards}
        assert float(rewards["end_effector_position_tracking"][2]) == pytest.approx(0.03, abs=1e-5)
        assert float(rewards["end_effector_position_tracking_fine_grained"][2]) == pytest.approx(
            1.0 - math.tanh(0.3), abs=1e-4)
        assert float(rewards["end_effector_orientation_tracking"][2]) == pytest.approx(0.4,
                                                                                    abs=1e-4)
        # Success: within 5 cm and 0.35 rad, judged on the step's errors. 3 cm and 0.4 rad is
        # not; 3 cm and 0 rad is, though the command expires at that step and is drawn again.
        made.after_step()
        assert not bool(env.task._success.compute()[2])
        made.command[2, 3:] = torch.from_numpy(site_quat)
        made.time_left[2] = 0.0
        env.task.robot.forget_derived()
        made.after_step()
        assert not torch.equal(made.command[2, 3:], torch.from_numpy(site_quat).to(made.command))
        assert bool(env.task._success.compute()[2])
        assert float(made.metrics()["position_error"][2]) == pytest.approx(0.03, abs=1e-5)
    finally:
        env.close()


FLOATING = """<mujoco model="floating_arm"><worldbody><body name="base" pos="0 0 1">
  <freejoint/><geom size="0.1"/>
  <body name="link"><joint name="shoulder" range="-1 1"/><geom size="0.05" pos="0.2 0 0"/>
    <site name="tip" pos="0.3 0 0"/></body></body></worldbody>
  <actuator><position joint="shoulder" kp="10"/></actuator></mujoco>"""


class _PoseCommands(c.Group):
    ee_pose: c.UniformPoseCommand | None = c.UniformPoseCommand(site="tip", base_body="base")


class _FloatingArm(c.RobotTaskConfig):
    num_envs: int = 2
    default_pose: str | None = None
    commands: _PoseCommands = _PoseCommands()


def test_a_pose_command_on_a_floating_robot_is_one_line(tmp_path):
    path = tmp_path / "model.xml"
    path.write_text(FLOATING)
    spec = TaskSpec(name="floating", task=RobotTask, config=_FloatingArm, model=path)
    with pytest.raises(LabError) as err:
        LabVecEnv(spec, _FloatingArm())
    assert err.value.message == ("a pose command's frame is a fixed base's body ('base'), and "
                                 "model 'floating_arm' floats (a free joint)")


def test_home_names_joints_of_the_model_or_is_one_line():
    spec = mujoco.MjSpec.from_string("""<mujoco model="arm"><worldbody><body name="b">
        <joint name="shoulder" range="-1 1"/><geom size="0.1"/></body></worldbody>
        <actuator><position joint="shoulder"/></actuator></mujoco>""")
    arm = {"arm": Actuators(joints=["shoulder"], effort_limit=5.0, armature=0.01,
                            action_scale=0.5)}
    robot_model.apply(spec, RobotDescription(base="fixed", actuators=arm, home={"sh.*": 0.3}))
    assert spec.compile().key("home").qpos.tolist() == [0.3]
    spec = mujoco.MjSpec.from_string(spec.to_xml())
    with pytest.raises(LabError) as err:
        robot_model.apply(spec, RobotDescription(base="fixed", actuators=arm, home={"elbow": 1}))
    assert err.value.message == "env.robot.home's 'elbow' matches no joint of model 'arm'"


def test_panda_reach_trains_plays_and_exports_from_the_command_line(tmp_path):
    env = {"LAB_LOGS_DIR": str(tmp_path)}
    trained = CliRunner().invoke(app, ["train", "--task", "panda-reach", "--framework",
                                       "rsl_rl", "--num-envs", "8", "--max-iterations", "2"],
                                 env=env)
    assert trained.exit_code == 0, trained.output
    played = CliRunner().invoke(app, ["play", "--last", "--episodes", "2", "--num-envs", "2"],
                                env=env)
    assert played.exit_code == 0 and "2 episodes" in played.output, played.output
    exported = CliRunner().invoke(app, ["export", "onnx", "--last"], env=env)
    assert exported.exit_code == 0, exported.output
