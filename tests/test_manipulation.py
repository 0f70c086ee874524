"""Arms: panda-reach on Menagerie's Franka Panda, its pose command against MuJoCo's own
kinematics, the reaching rewards and success against hand-computed cases, and the robot
description's home pose."""

from __future__ import annotations

import json
import math

import mujoco
import numpy as np
import pytest
import torch
from conftest import needs_menagerie, needs_warp
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.envs import markers
from labcli.envs.env import LabVecEnv
from labcli.envs.mdp import config as c
from labcli.envs.mdp import robot_model
from labcli.envs.mdp.description import Actuators, RobotDescription
from labcli.envs.mdp.task import RobotTask
from labcli.envs.render import scene as scene_renderer
from labcli.envs.spec import TaskSpec
from labcli.errors import LabError
from labcli.gym import make_env
from labcli.plugins import registry
from labcli.runs import config

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


def test_reached_latches_the_closest_approach_to_each_target_until_the_next_is_drawn():
    env = reach(4, "env.commands.ee_pose.reached_within=0.05")
    try:
        for _ in range(60):
            env.step(torch.zeros(4, 8))
        made = env.task.command("ee_pose")
        site = torch.from_numpy(mujoco_site_pose(env, 2)[0]).to(made.command)

        def step_with_target(offset_z: float, expires: bool = False) -> float:
            made.command[2, :3] = site + torch.tensor([0.0, 0.0, offset_z]).to(site)
            made.command[:, :3][[0, 1, 3]] = site + 1.0  # a metre away: never reached
            made.time_left.fill_(0.0 if expires else 1.0)
            env.task.robot.forget_derived()
            made.after_step()
            reached = made.metrics()["reached"]
            assert reached[[0, 1, 3]].tolist() == [0.0, 0.0, 0.0]
            return float(reached[2])

        assert step_with_target(0.2) == 0.0
        assert step_with_target(0.04) == 1.0
        assert step_with_target(0.3) == 1.0  # latched: it came within 5 cm of this target
        assert step_with_target(0.3, expires=True) == 1.0  # judged before the next is drawn
        assert step_with_target(0.3) == 0.0  # a new target, not yet reached
        assert step_with_target(0.049) == 1.0
        twin = reach(4, "env.commands.ee_pose.reached_within=0.05")  # resumed from env's state
        try:
            twin.resume_from(env.get_state())
            twin.reset()
            resumed = twin.task.command("ee_pose")
            assert torch.equal(resumed.since_drawn, made.since_drawn)
            assert torch.equal(resumed.closest, made.closest)
        finally:
            twin.close()
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


def lift(n: int, *overrides: str):
    env = make_env("panda-lift", num_envs=n, seed=0, overrides=[*QUIET, *overrides],
                   backend="cpu", device="cpu")
    env.reset()
    return env


def hand_down_at(model: mujoco.MjModel, qpos: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """The arm's joint angles that put the gripper site at `pos`, pointing down (the hand's
    fingers along the world's y): damped least squares on MuJoCo's site Jacobian."""
    data, site = mujoco.MjData(model), model.site("gripper").id
    data.qpos[:] = qpos
    arm = [model.joint(f"joint{i}").qposadr[0] for i in range(1, 8)]
    down = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    for _ in range(200):
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        error, turn = np.zeros(6), np.zeros(4)
        error[:3] = pos - data.site_xpos[site]
        mujoco.mju_mat2Quat(turn, (down @ data.site_xmat[site].reshape(3, 3).T).ravel())
        mujoco.mju_quat2Vel(error[3:], turn, 1.0)
        if np.linalg.norm(error) < 1e-6:
            break
        jac_pos, jac_rot = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jac_pos, jac_rot, site)
        jac = np.vstack([jac_pos, jac_rot])[:, arm]
        data.qpos[arm] += jac.T @ np.linalg.solve(jac @ jac.T + 1e-4 * np.eye(6), error)
    assert np.linalg.norm(error) < 1e-4
    return data.qpos[arm].copy()


def grasp(env) -> list[torch.Tensor]:
    """The actions of a scripted grasp of each env's cube where it starts: the hand 15 cm above
    the cube, down to it along a straight line, the gripper closed, straight up 25 cm."""
    model = env.sim.model
    default = env.task.robot.default_joint_pos[0, :7].double().cpu().numpy()
    qpos = env.sim.qpos.double().cpu().numpy()
    cubes, arm = qpos[:, 9:12].copy(), [model.joint(f"joint{i}").qposadr[0] for i in range(1, 8)]
    # Heights of the hand over the cube, one per step, and the gripper's action. Each step's
    # joint targets start from the last ones: a jump of many centimetres would swing the hand
    # along a curve, and its pads clear the cube's sides by 5 mm.
    heights = ([0.15] * 40 + np.linspace(0.15, 0.0, 50).tolist() + [0.0] * 55
               + np.linspace(0.0, 0.25, 40).tolist() + [0.25] * 20)
    grips = [1.0] * 120 + [-1.0] * 85
    plan = []
    for height, grip in zip(heights, grips, strict=True):
        rows = []
        for i, cube in enumerate(cubes):
            qpos[i, arm] = hand_down_at(model, qpos[i], cube + [0.0, 0.0, height])
            rows.append(np.append((qpos[i, arm] - default) / 0.5, grip))
        plan.append(torch.tensor(np.stack(rows), dtype=torch.float32))
    return plan


def test_a_scripted_grasp_lifts_the_cube_and_the_lift_terms_see_it():
    """Above the cube, down to it, the gripper closed, up by 25 cm: the binary action closes
    the fingers on the cube, which leaves the floor; the observation, the rewards and success
    against hand-computed values."""
    env = lift(2)
    try:
        task = env.task
        assert not task.robot.floating  # the cube's free joint is not the arm's base
        plan = grasp(env)
        for action in plan[:120]:
            env.step(action)
        assert float(env.sim.qpos[0, 7]) == pytest.approx(0.04, abs=1e-3)  # open: 4 cm
        assert task.reward_terms()["grasping_object"].tolist() == [0.0, 0.0]
        for action in plan[120:145]:
            env.step(action)
        closed = env.sim.qpos[:, 7].clone()
        assert ((closed > 0.015) & (closed < 0.025)).all()  # on the 4 cm cube's sides, not shut
        grasped = []
        for action in plan[145:]:
            env.step(action)
            grasped.append(task.reward_terms()["grasping_object"])
        # Both pads touch the cube throughout but for one step in ten or fewer: the fingers
        # chatter on it, and a contact sensor reads the last physics step's contacts.
        assert (torch.stack(grasped).mean(dim=0) > 0.85).all()
        held = env.sim.qpos[0, 9:12].double()
        assert float(held[2]) > 0.2 and float(env.sim.qpos[1, 11]) > 0.2
        assert torch.allclose(env.sim.qpos[:, 7], closed, atol=1e-3)
        # The arm stands at the origin unturned: the base frame is the world's.
        assert env.task.observations()[0, 16:19].double() == pytest.approx(held, abs=1e-6)
        command = task.command("object_pose")
        target = command.command[0, :3].double()
        rewards = task.reward_terms()
        distance = float(torch.linalg.vector_norm(target - held))
        assert float(rewards["grasping_object"][0]) == 1.0
        assert float(rewards["lifting_object"][0]) == 1.0
        assert float(rewards["object_goal_tracking"][0]) == pytest.approx(
            1.0 - math.tanh(distance / 0.2), abs=1e-5)
        assert float(rewards["object_goal_tracking_fine_grained"][0]) == pytest.approx(
            1.0 - math.tanh(distance / 0.05), abs=1e-5)
        assert float(rewards["reaching_object"][0]) > 1.0 - math.tanh(0.01 / 0.1)
        # Success: the cube within 5 cm of the target at the step's end; here the target put
        # 3 cm above where the cube is held.
        command.command[0, :3] = held.to(command.command) + torch.tensor([0.0, 0.0, 0.03])
        task.robot.forget_derived()
        command.after_step()
        assert float(command.errors[0, 0]) == pytest.approx(0.03, abs=1e-3)
        assert bool(task._success.compute()[0])
    finally:
        env.close()


@pytest.mark.parametrize(("overrides", "least", "most"), [
    ([], 0.003, 0.05), (["env.noslip_iterations=2"], -0.0005, 0.0005)])
def test_a_held_cube_creeps_down_the_fingers_unless_the_noslip_solver_holds_it(
        overrides, least, most):
    """The scripted grasp's cube held 25 cm up for 5 s more, the hand still: MuJoCo's soft
    contacts let it slide down the pads (6-16 mm with the scene's own contacts, nearer the
    fingertips' edge with every second); two iterations of the noslip solver hold it to a
    fraction of a millimetre."""
    env = lift(2, "env.episode_length_s=20", *overrides)
    try:
        assert env.sim.model.opt.noslip_iterations == (2 if overrides else 0)
        plan = grasp(env)
        for action in plan:
            env.step(action)

        def below_hand() -> np.ndarray:
            return np.array([mujoco_site_pose(env, i)[0][2] - float(env.sim.qpos[i, 11])
                             for i in range(2)])

        start = below_hand()
        for _ in range(250):
            env.step(plan[-1])
        assert float(env.sim.qpos[0, 11]) > 0.15 and float(env.sim.qpos[1, 11]) > 0.15
        crept = below_hand() - start
        assert ((crept > least) & (crept < most)).all(), crept
    finally:
        env.close()


@pytest.mark.parametrize(("held_by", "lifted"), [(None, 0.0), ("null", 1.0)])
def test_a_cube_in_the_air_counts_as_lifted_only_between_both_fingers(held_by, lifted):
    """A cube 30 cm up, away from the open hand (as a batted cube flies): no grasp, neither
    lifted nor carried toward the target; with Isaac Lab's unconditioned terms (held_by
    null) it would count as lifted."""
    overrides = [] if held_by is None else [
        f"env.rewards.{term}.held_by={held_by}" for term in
        ("lifting_object", "object_goal_tracking", "object_goal_tracking_fine_grained")]
    env = lift(1, *overrides)
    try:
        env.sim.qpos[0, 11] = 0.3
        env.step(torch.zeros(1, 8))
        assert float(env.sim.qpos[0, 11]) > 0.29
        rewards = env.task.reward_terms()
        assert float(rewards["grasping_object"][0]) == 0.0
        assert float(rewards["lifting_object"][0]) == lifted
        assert (float(rewards["object_goal_tracking"][0]) > 0.0) == bool(lifted)
    finally:
        env.close()


@pytest.mark.parametrize(("override", "message", "hint"), [
    ('env.rewards.grasping_object.fingers=["left_fingr"]', "has no body named 'left_fingr'",
     "did you mean 'left_finger', 'right_finger'?"),
    ("env.rewards.reaching_object.site=hand", "has no site named 'hand'",
     "its sites are 'gripper'"),
])
def test_a_term_s_sensor_on_a_name_the_model_lacks_is_one_line(override, message, hint):
    """Before, MuJoCo's compile error of the sensor: a traceback."""
    with pytest.raises(LabError) as err:
        lift(1, override)
    assert err.value.message == f"model 'panda scene' {message}"
    assert err.value.hint == hint


@pytest.mark.gpu
@needs_warp()
def test_both_backends_grasp_and_lift_the_cube_alike():
    """MuJoCo Warp holds the cube between the finger pads as MuJoCo does: from the same state,
    the same scripted grasp lifts it on both, to within a centimetre of each other, and both
    see it grasped and lifted while it is carried (their contact sensors)."""
    from backends import lift_and_copy

    cpu = lift(4)
    gpu = make_env("panda-lift", num_envs=4, seed=0, overrides=QUIET, backend="warp",
                   device="cuda")
    gpu.reset()
    lift_and_copy(cpu, gpu, height=0.0)
    try:
        held = {"grasping_object": [[], []], "lifting_object": [[], []]}
        for step, action in enumerate(grasp(cpu)):
            cpu.step(action)
            gpu.step(action.cuda())
            for side, env in enumerate((cpu, gpu)):
                rewards = env.task.reward_terms()
                for term, seen in held.items():
                    if step >= 160:  # the cube well off the floor
                        seen[side].append(rewards[term].cpu())
        cubes = [env.sim.qpos[:, 9:12].double().cpu() for env in (cpu, gpu)]
        assert (cubes[0][:, 2] > 0.2).all() and (cubes[1][:, 2] > 0.2).all()
        assert torch.allclose(cubes[0], cubes[1], atol=0.01)
        # Most steps: the fingers' chatter drops a contact now and then, differently on each.
        for term, seen in held.items():
            for side in seen:
                assert (torch.stack(side).mean(dim=0) > 0.75).all(), term
    finally:
        cpu.close()
        gpu.close()


def test_the_cube_is_put_back_in_its_box_at_each_reset_on_the_floor():
    env = lift(64)
    try:
        cube = env.sim.qpos[:, 9:16].double()
        assert ((cube[:, 0] >= 0.4) & (cube[:, 0] <= 0.6)).all()
        assert ((cube[:, 1] >= -0.25) & (cube[:, 1] <= 0.25)).all()
        assert torch.equal(cube[:, 2], torch.full((64,), 0.03, dtype=cube.dtype))
        assert torch.equal(cube[:, 3:], torch.tensor([[1.0, 0.0, 0.0, 0.0]]).expand(64, 4).to(
            cube))
        assert cube[:, 1].std() > 0.1  # drawn per env
        target = env.task.command("object_pose").command
        assert ((target[:, 2] >= 0.25) & (target[:, 2] <= 0.5)).all()
    finally:
        env.close()


def test_a_gripper_s_binary_action_is_exported_with_its_two_targets():
    env = lift(2)
    try:
        joints = env.describe()["deployment"]["joints"]
        assert [("binary" in j) for j in joints] == [False] * 7 + [True]
        assert joints[7]["binary"] == {"open": 0.04, "close": 0.0}
        commands = [a["command"] for a in env.describe()["actions"]]
        assert commands[7] == "ctrl = 0.04 if action >= 0, else 0"
        env.step(torch.tensor([[0.0] * 7 + [0.0], [0.0] * 7 + [-0.001]]))
        assert env.sim.ctrl[:, 7].tolist() == [0.04, 0.0]
    finally:
        env.close()


def test_a_target_marker_is_drawn_at_the_command_s_target_in_the_world():
    env = lift(2)
    try:
        made = env.task.command("object_pose")
        marker, = env.markers()
        assert marker.pos == pytest.approx(made.target_world()[0].tolist())
        model = env.sim.model
        scene = mujoco.MjvScene(model, maxgeom=100)
        drawn = markers.draw
        drawn(scene, [marker])
        assert scene.ngeom == 4  # a sphere and the frame's three axes
        assert scene.geoms[0].pos.tolist() == pytest.approx(marker.pos)
        full = mujoco.MjvScene(model, maxgeom=2)
        drawn(full, [marker])  # no room past maxgeom: what fits is drawn, nothing fails
        assert full.ngeom == 2
    finally:
        env.close()


def test_an_arm_s_video_frames_it_from_the_front():
    env = lift(1)
    camera = scene_renderer._following(env.sim.model)
    env.close()
    assert camera.type == mujoco.mjtCamera.mjCAMERA_FREE
    assert 0.8 < camera.distance < 2.5  # where the arm reaches, not metres off
    assert 0.0 < camera.lookat[0] < 0.6 and 0.1 < camera.lookat[2] < 0.8


@pytest.mark.parametrize("task", ["panda-reach", "panda-lift"])
def test_panda_tasks_train_play_and_export_from_the_command_line(tmp_path, task):
    env = {"LAB_LOGS_DIR": str(tmp_path)}
    trained = CliRunner().invoke(app, ["train", "--task", task, "--framework",
                                       "rsl_rl", "--num-envs", "8", "--max-iterations", "2"],
                                 env=env)
    assert trained.exit_code == 0, trained.output
    played = CliRunner().invoke(app, ["play", "--last", "--episodes", "2", "--num-envs", "2"],
                                env=env)
    assert played.exit_code == 0 and "2 episodes" in played.output, played.output
    assert "the task's metrics, means over the 2 episodes that ended: " in played.output
    exported = CliRunner().invoke(app, ["export", "onnx", "--last"], env=env)
    assert exported.exit_code == 0, exported.output
    # The plain-MuJoCo check replays floating robots: an arm's export is one line saying so.
    checked = CliRunner().invoke(app, ["sim2sim", "--last", "--episodes", "1"], env=env)
    assert checked.exit_code == 2 and "bolted to the world" in checked.output, checked.output


def test_play_reports_the_task_s_metrics_of_the_episodes_that_ended(tmp_path):
    """The zero agent holds the hand at home, over the cube: the cube stays on the floor, its
    centre 22-47 cm under every target (the targets' 25-50 cm over the base, the cube's 3 cm),
    upright as each target asks."""
    from labcli.runs import play as plays

    _, eps = plays.sanity("panda-lift", "zero", episodes=3, num_envs=3, logs_dir=tmp_path)
    assert eps.ended == 3
    assert set(eps.task_metrics) == {"object_pose/position_error",
                                     "object_pose/orientation_error", "object_pose/reached"}
    assert eps.task_metrics["object_pose/reached"] == 0.0
    assert 0.22 <= eps.task_metrics["object_pose/position_error"] <= 0.8
    assert eps.task_metrics["object_pose/orientation_error"] < 0.01


def test_the_summary_keeps_the_last_ended_episodes_figures(tmp_path, monkeypatch):
    """panda-reach's 12 s episodes end together every 15 iterations of 24 steps: the 16th
    ends none. A physics buffer's overflow in it (as MuJoCo Warp reports them) must not blank
    the run's final return and success."""
    from labcli.envs.sim.cpu import CpuSim

    monkeypatch.setattr(CpuSim, "pop_overflows", lambda self: {"ITERATIONS": 1.0})
    trained = CliRunner().invoke(app, ["train", "--task", "panda-reach", "--framework", "rsl_rl",
                                       "--num-envs", "4", "--max-iterations", "16"],
                                 env={"LAB_LOGS_DIR": str(tmp_path)})
    assert trained.exit_code == 0, trained.output
    summary, = tmp_path.glob("rsl_rl/panda-reach/*/summary.json")
    figures = json.loads(summary.read_text())
    assert figures["mean_return"] is not None and figures["success_rate"] is not None
    assert "success" in trained.output.splitlines()[-1]


def test_a_reward_weight_changes_after_its_steps_and_a_restored_env_keeps_it():
    """panda-lift's curriculum, brought to 3 steps: the action-rate weight is Isaac Lab's -1e-4
    (per second: x 0.02 s a step) for 3 steps, then -0.5; the weighted term in the step's reward
    follows; an env restored from a state saved after the change weighs the new way."""
    env = lift(2, "env.curriculum.action_rate.num_steps=3")
    other = lift(2, "env.curriculum.action_rate.num_steps=3")
    try:
        column = env.reward_names.index("action_rate")
        seen = []
        for step in range(5):
            action = torch.full((2, 8), 0.1 * (step + 1))
            env.step(action)
            seen.append(float(env._weights[0, column]))
        assert seen == pytest.approx([-1e-4 * 0.02] * 2 + [-0.5 * 0.02] * 3)
        rate = float(env.task.reward_terms()["action_rate"][0])
        assert float(env._weighted[0, column]) == pytest.approx(-0.5 * 0.02 * rate, rel=1e-5)
        assert float(other._weights[0, column]) == pytest.approx(-1e-4 * 0.02)
        other.set_state(env.get_state())
        assert torch.equal(other._weights, env._weights)
        assert torch.equal(other.task.steps, torch.full((2,), 5))
    finally:
        env.close()
        other.close()


def test_lift_s_cpu_defaults_delay_the_penalties_and_the_gpu_s_keep_isaac_lab_s():
    """panda-lift on the CPU: 1,024 envs for 2,000 iterations, the smoothness penalties heavier
    after 24,000 env steps (1,000 iterations), by when 2 cores have learnt to grasp; on the GPU
    4,096 envs, 1,500 iterations and Isaac Lab's 10,000, for every framework."""
    spec = registry.get_task("panda-lift")
    for name in ("rsl_rl", "skrl", "sb3", "rl_games"):
        fw = registry.get_framework(name)
        (cpu, cpu_agent), (gpu, gpu_agent) = (config.resolve(spec, fw, gpu_scale=scale)
                                              for scale in (False, True))
        assert (cpu.num_envs, cpu_agent.max_iterations) == (1024, 2000), name
        assert (gpu.num_envs, gpu_agent.max_iterations) == (4096, 1500), name
        for term in ("action_rate", "joint_vel"):
            steps = (getattr(cpu.curriculum, term).num_steps,
                     getattr(gpu.curriculum, term).num_steps)
            assert steps == (24_000, 10_000), (name, term)


def test_a_curriculum_of_a_reward_the_task_lacks_is_one_line():
    with pytest.raises(LabError) as err:
        lift(1, "env.curriculum.action_rate.term=smoothness")
    assert err.value.message == ("env.curriculum names reward term 'smoothness', which "
                                 "env.rewards does not have")
