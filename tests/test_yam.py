"""yam-lift: mjlab's Lift-Cube-Yam on Menagerie's i2rt YAM with panda-lift's rewards, and the
building blocks it added (a cube added to the model, a site and the collision set of a robot
description, mjlab's staged lift rewards, a grasp that squeezes, an end effector's contact with
the ground, a curriculum in stages)."""

import math

import mujoco
import numpy as np
import pytest
import torch
from conftest import needs_menagerie, needs_warp
from lab_manipulation.config import YamLiftRewards
from lab_manipulation.scripted import CUBE_POS, grasp, holding, pinch_down_at, plan, settle
from lab_manipulation.yam import FINGERS

from labcli.envs.mdp import config as c
from labcli.envs.mdp import objects, robot_model
from labcli.envs.mdp.description import Collisions, RobotDescription
from labcli.errors import LabError
from labcli.gym import make_env

pytestmark = needs_menagerie("i2rt_yam")
REST = 0.01  # the 2 cm half-size cube's centre resting on Menagerie's floor, 1 cm below the base


def lift(n: int, *overrides: str, **config):
    env = make_env("yam-lift", num_envs=n, seed=0, backend="cpu", device="cpu",
                   overrides=["env.observation_noise=false", *overrides], **config)
    env.reset()
    return env


def press(env) -> list[torch.Tensor]:
    """Fingertips pressing the cube down: the pinch lowered to 1 cm over the cube's centre
    with the fingers 3 mm from shut, so that both tips land on its top face."""
    heights = [0.12] * 40 + np.linspace(0.12, 0.01, 60).tolist() + [0.01] * 40
    return plan(env, heights, [0.003] * len(heights))


class _StagedRewards(YamLiftRewards):
    """The task's rewards and mjlab's staged ones beside them."""

    lift: c.ObjectStagedReach | None = c.ObjectStagedReach(
        weight=1.0, object="cube", command="lift_height", site="pinch", reaching_std=0.2,
        bringing_std=0.3)
    lift_precise: c.ObjectGoalDistance | None = c.ObjectGoalDistance(
        weight=1.0, object="cube", command="lift_height", std=0.05, kernel="gaussian",
        minimal_height=None)


def test_a_scripted_grasp_lifts_the_cube_and_the_lift_terms_see_it():
    """Over the cube with the gripper open, down to it, closed, up by 10 cm: the pads hold the
    4 cm cube (the fingers stop 2 cm out), it leaves the floor with the hand, and the
    observations, the task's rewards and mjlab's staged ones match hand-computed values."""
    env = lift(2, rewards=_StagedRewards())
    try:
        model, task = env.sim.model, env.task
        assert not task.robot.floating  # the cube's free joint is not the arm's base
        settle(env)
        assert env.sim.qpos[:, 10].tolist() == pytest.approx([REST, REST], abs=3e-4)
        for action in grasp(env):
            env.step(action)
        held = env.sim.qpos[:, CUBE_POS].double()
        assert (held[:, 2] > REST + 0.08).all()  # the hand rose 10 cm
        assert env.sim.qpos[:, 6].double().numpy() == pytest.approx([0.02, 0.02], abs=1e-3)
        # Observations: the cube from the pinch and the target from the cube, in the base's
        # frame (the arm stands at the origin unturned: the world's). The pinch is read from a
        # frame sensor, which MuJoCo computes at the last physics step's start: 0.1 mm back.
        names = task.observation_names
        obs = env.task.observations()[0].double()
        pinch = torch.tensor(_site(model, env, 0, "pinch"), dtype=torch.float64)
        ee_to_cube = obs[names.index("ee_to_cube.x"):names.index("ee_to_cube.z") + 1]
        assert ee_to_cube == pytest.approx((held[0] - pinch).tolist(), abs=2e-4)
        target = task.command("lift_height").command[0, :3].double()
        cube_to_goal = obs[names.index("cube_to_goal.x"):names.index("cube_to_goal.z") + 1]
        assert cube_to_goal == pytest.approx((target - held[0]).tolist(), abs=1e-6)
        rewards = {name: float(value[0]) for name, value in task.reward_terms().items()}
        reach, bring = float(ee_to_cube.norm()), float((target - held[0]).norm())
        # The task's: held between the pads (squeezed), lifted, carried.
        assert rewards["reaching_object"] == pytest.approx(1.0 - math.tanh(reach / 0.1),
                                                           rel=1e-5)
        assert rewards["grasping_object"] == rewards["lifting_object"] == 1.0
        assert rewards["object_goal_tracking"] == pytest.approx(1.0 - math.tanh(bring / 0.2),
                                                                rel=1e-5)
        assert rewards["object_goal_tracking_fine_grained"] == pytest.approx(
            1.0 - math.tanh(bring / 0.05), rel=1e-5, abs=1e-7)
        # mjlab's: reach x (1 + bring), and the precise bring, Gaussian kernels.
        assert rewards["lift"] == pytest.approx(
            math.exp(-reach**2 / 0.2**2) * (1.0 + math.exp(-bring**2 / 0.3**2)), rel=1e-5)
        assert rewards["lift_precise"] == pytest.approx(math.exp(-bring**2 / 0.05**2),
                                                        rel=1e-5, abs=1e-12)
        assert not env.task.terminations()["ee_ground_collision"].any()
    finally:
        env.close()


class _GraspRewards(YamLiftRewards):
    touched: c.ObjectGrasped | None = c.ObjectGrasped(weight=1.0, object="cube",
                                                      fingers=FINGERS)
    squeezed: c.ObjectGrasped | None = c.ObjectGrasped(weight=1.0, object="cube",
                                                       fingers=FINGERS, squeeze=0.8)


def test_the_scripted_grasp_holds_up_an_arm_whose_weight_is_not_compensated():
    """yam-lift's YAM weighs on its servos (mjlab's): they sag under the arm's weight unless
    their targets are raised by its gravity torques over their stiffness, and then the grasp
    lifts the cube. With Menagerie's gravity compensation the targets are the joints' angles."""
    env = lift(2)
    try:
        settle(env)
        home = env.task.robot.default_joint_pos[0, :6].double().numpy()
        sagged = env.sim.qpos[0, :6].double().numpy()
        assert np.abs(sagged - home).max() > 0.1  # rad, the elbow and wrist under their weight
        qpos = env.sim.qpos[0].double().numpy()
        offsets = holding(env.sim.model, qpos)
        assert np.abs(offsets).max() > 0.1
        data = mujoco.MjData(env.sim.model)
        data.qpos[:] = qpos
        mujoco.mj_forward(env.sim.model, data)
        dofs = [env.sim.model.joint(f"joint{i}").dofadr[0] for i in range(1, 7)]
        assert offsets * env.sim.model.actuator_gainprm[:6, 0] == pytest.approx(
            data.qfrc_bias[dofs], rel=1e-9)
        for action in grasp(env):
            env.step(action)
        assert (env.sim.qpos[:, CUBE_POS][:, 2].double() > REST + 0.08).all()
    finally:
        env.close()
    env = lift(1, "env.robot.gravity_compensation=true")
    try:
        weightless = holding(env.sim.model, env.sim.qpos[0].double().numpy())
        assert np.abs(weightless).max() < 1e-9
    finally:
        env.close()


@pytest.mark.parametrize(("script", "squeezed", "share"), [(press, False, (0.95, 1.0)),
                                                          (grasp, True, (0.1, 0.3))])
def test_fingertips_pressing_the_cube_down_touch_it_and_squeeze_tells_them_from_a_grasp(
        script, squeezed, share):
    """Both fingertips pressing the cube into the floor touch it as a grasp's pads do (the
    grasp term without `squeeze` pays for both), but push it the same way: the net force of
    their contacts is nearly the sum of their sizes, where pads holding it in the air push it
    from opposing sides (about 0.2: its weight over the squeeze). `squeeze=0.8` pays for the
    grasp alone."""
    env = lift(2, rewards=_GraspRewards())
    try:
        settle(env)
        for action in script(env):
            env.step(action)
        rewards = env.task.reward_terms()
        assert rewards["touched"].tolist() == [1.0, 1.0]
        assert rewards["squeezed"].tolist() == ([1.0, 1.0] if squeezed else [0.0, 0.0])
        model, height = env.sim.model, env.sim.qpos[:, CUBE_POS][:, 2]
        assert ((height < REST) if not squeezed else (height > REST + 0.08)).all()
        # Each finger's contact sensor: the number of contacts, then their net force.
        starts = [model.sensor(s.name).adr[0] + 1 for s in objects.grasp_sensors("cube", FINGERS)]
        forces = torch.stack([env.sim.sensordata[:, i:i + 3].double() for i in starts], dim=1)
        ratio = forces.sum(dim=1).norm(dim=1) / forces.norm(dim=2).sum(dim=1)
        assert ((ratio > share[0]) & (ratio < share[1])).all()
    finally:
        env.close()


@pytest.mark.gpu
@needs_warp()
def test_both_backends_grasp_and_lift_the_cube_alike():
    """MuJoCo Warp holds the cube between the YAM's finger pads as MuJoCo does: from the same
    state, the same scripted grasp lifts it 9 cm or more on both, to within a centimetre of
    each other."""
    from backends import lift_and_copy

    cpu = lift(4)
    gpu = make_env("yam-lift", num_envs=4, seed=0, overrides=["env.observation_noise=false"],
                   backend="warp", device="cuda")
    gpu.reset()
    settle(cpu)
    lift_and_copy(cpu, gpu, height=0.0)
    try:
        for action in grasp(cpu):
            cpu.step(action)
            gpu.step(action.cuda())
        cubes = [env.sim.qpos[:, CUBE_POS].double().cpu() for env in (cpu, gpu)]
        assert (cubes[0][:, 2] > REST + 0.08).all() and (cubes[1][:, 2] > REST + 0.08).all()
        assert torch.allclose(cubes[0], cubes[1], atol=0.01)
    finally:
        cpu.close()
        gpu.close()


def _site(model: mujoco.MjModel, env, i: int, name: str) -> list[float]:
    data = mujoco.MjData(model)
    data.qpos[:] = env.sim.qpos[i].double().numpy()
    mujoco.mj_kinematics(model, data)
    return data.site(name).xpos.tolist()


def test_the_hand_pressed_on_the_floor_ends_the_episode_and_only_the_gripper_collides():
    env = lift(1)
    try:
        model = env.sim.model
        colliding = {model.body(int(model.geom_bodyid[g])).name for g in range(model.ngeom)
                     if model.geom_contype[g] or model.geom_conaffinity[g]}
        assert colliding == {"world", "link_6", "lf_rot", "lf_down", "rf_rot", "rf_down", "cube"}
        pads = [g for g in range(model.ngeom) if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE
                and model.body(int(model.geom_bodyid[g])).name in ("lf_down", "rf_down")]
        assert len(pads) == 12
        assert {int(model.geom_condim[g]) for g in pads} == {6}
        assert {int(model.geom_priority[g]) for g in pads} == {1}
        # The hand driven 5 cm into the floor at its home reach.
        qpos = env.sim.qpos[0].double().numpy().copy()
        down = pinch_down_at(model, qpos, np.array([0.3, 0.2, -0.05]), 0.0)
        default = env.task.robot.default_joint_pos[0].double().numpy()
        scales = np.array([g.scale(2.0, 2.0) for g in env.task.cfg.robot.actuators.values()])
        action = torch.tensor((np.append(down, 0.0375) - default[:7]) / scales,
                              dtype=torch.float32)[None]
        ended = False
        for _ in range(150):
            _, _, terminated, _, _ = env.step(action)
            ended |= bool(terminated[0])
        assert ended
    finally:
        env.close()


def test_the_joint_speed_penalty_grows_in_mjlab_s_stages():
    env = lift(1)
    try:
        task = env.task
        column = task.cfg.rewards.terms()
        index = [name for name, _ in column].index("joint_vel_hinge")
        for steps, weight in ((0, -0.01), (11_999, -0.1), (23_998, -0.1), (23_999, -1.0)):
            task.steps.fill_(steps)
            env.step(torch.zeros(1, 7))
            # The env counts this step before the curriculum runs: 12,000 and 24,000 then. Each
            # weight is per second, as mjlab's: times the 20 ms step.
            assert float(task.reward_weights[0, index]) == pytest.approx(weight * 0.02)
    finally:
        env.close()


def test_stages_out_of_order_a_site_dropped_and_unmatched_collisions_are_one_line():
    with pytest.raises(ValueError, match="give them in order"):
        c.RewardWeight(term="x", weight=-0.1, num_steps=100, then=[(50, -1.0)])
    with pytest.raises(ValueError, match="it needs body"):
        c.UniformPoseCommand(site="hand", base_body="base", place={"x": (0.0, 0.1)})
    spec = mujoco.MjSpec.from_string("""<mujoco model="arm"><worldbody><body name="link">
        <joint name="elbow"/><geom size="0.1"/></body></worldbody>
        <actuator><position joint="elbow"/></actuator></mujoco>""")
    robot = RobotDescription(base="fixed", actuators={"arm": {"joints": ["elbow"],
                                                              "effort_limit": 1.0,
                                                              "armature": 0.01}},
                             collisions=[Collisions(bodies=["hand"])])
    with pytest.raises(LabError) as err:
        robot_model.apply(spec, robot)
    assert err.value.message == ("env.robot.collisions' entry for bodies ['hand'] matches no "
                                 "collision geom of the robot")


def test_the_yam_s_gains_and_action_scales_are_mjlab_s():
    """mjlab's YAM_ACTION_SCALE: a quarter of each motor's effort over its stiffness, the
    stiffness from the joint's effective inertia at 2 Hz (the gripper's at 1 Hz)."""
    env = lift(1)
    try:
        model = env.sim.model
        kp = model.actuator_gainprm[:, 0]
        assert kp.tolist() == pytest.approx([0.123153 * (4 * math.pi) ** 2,
                                             0.277411 * (4 * math.pi) ** 2,
                                             0.232763 * (4 * math.pi) ** 2,
                                             0.030154 * (4 * math.pi) ** 2,
                                             0.009126 * (4 * math.pi) ** 2,
                                             0.002868 * (4 * math.pi) ** 2,
                                             2.781624 * (2 * math.pi) ** 2])
        gripper_force = 10.0 / (0.071 / 2.7) * 0.1
        assert model.actuator_forcerange[:, 1].tolist() == pytest.approx(
            [28.0] * 3 + [10.0] * 3 + [gripper_force])
        scales = [g.scale(2.0, 2.0) for g in env.task.cfg.robot.actuators.values()]
        assert scales == pytest.approx((0.25 * model.actuator_forcerange[:, 1] / kp).tolist())
    finally:
        env.close()


@pytest.mark.parametrize(("clip", "closed"), [(True, (0.0199, 0.0202)), (False, (0.018, 0.0193))])
def test_a_gripper_s_unclipped_targets_squeeze_the_cube_up_to_its_effort_limit(clip, closed):
    """Menagerie's gripper takes targets of 0-41 mm: shut on the 4 cm cube (the pads meet it
    at 20 mm) its servo squeezes with kp x 20 mm, 2.2 N, at most. Asked for -0.3 m with
    `clip_targets` false (yam-lift's, as mjlab's servos take it), the servo pushes with up to
    its effort limit (38 N), and the pads sink into the cube's soft contacts."""
    env = lift(1, f"env.robot.actuators.gripper.clip_targets={str(clip).lower()}")
    try:
        settle(env)
        heights = [0.12] * 40 + np.linspace(0.12, 0.0, 50).tolist() + [0.0] * 80
        for action in plan(env, heights, [0.0375] * 100 + [-0.3] * 70):
            env.step(action)
        assert bool(env.sim.model.actuator_ctrllimited[6]) is clip
        assert closed[0] < float(env.sim.qpos[0, 6]) < closed[1]
    finally:
        env.close()


def test_menagerie_s_gravity_compensation_of_the_yam_is_off_unless_asked_for():
    """Menagerie's YAM makes its links weightless (gravcomp 1), mjlab's copy does not:
    yam-lift takes it off every body of the robot, `gravity_compensation` true keeps it."""
    for setting, weightless in (([], False), (["env.robot.gravity_compensation=true"], True)):
        env = lift(1, *setting)
        try:
            model = env.sim.model
            robot = [model.body(f"link_{i}").id for i in range(2, 7)]
            assert (model.body_gravcomp[robot] == (1.0 if weightless else 0.0)).all()
            assert model.body_gravcomp[model.body("cube").id] == 0.0
        finally:
            env.close()


def test_each_target_drawn_later_drops_the_cube_anew_and_a_copy_of_the_env_does_the_same():
    """mjlab's LiftingCommand: a target drawn during the episode comes with the cube dropped
    at rest somewhere in its box (x 0.2-0.4 m, y -0.2-0.2 m, 1-4 cm up), by the next step's
    physics; an env restored from a state taken in between drops it alike."""
    fast = "env.commands.lift_height.resampling_time_range=[0.1,0.1]"  # a draw every 5 steps
    env, twin = lift(2, fast), lift(2, fast)
    try:
        command = env.task.command("lift_height")
        hold = torch.zeros(2, 7)
        for _ in range(5):
            env.step(hold)
        assert command.to_drop.all()
        where = env.sim.qpos[:, CUBE_POS].clone()
        twin.set_state(env.get_state())
        env.step(hold)
        twin.step(hold)
        assert not command.to_drop.any()
        dropped = env.sim.qpos[:, CUBE_POS].double()
        assert not torch.allclose(dropped, where.double())
        assert ((dropped[:, 0] > 0.2) & (dropped[:, 0] < 0.4)).all()
        assert (dropped[:, 1].abs() < 0.2).all()
        assert ((dropped[:, 2] > REST - 1e-3) & (dropped[:, 2] < REST + 0.031)).all()
        # Let go at rest: one physics step's fall at most.
        assert float(env.sim.qvel[:, 8:11].abs().max()) < 9.81 * 0.02 + 1e-6
        assert torch.equal(env.sim.qpos, twin.sim.qpos)
    finally:
        env.close()
        twin.close()


def test_an_object_or_a_site_the_model_cannot_take_is_one_line():
    with pytest.raises(LabError) as err:
        lift(1, "env.objects={arm: {size: [0.02, 0.02, 0.02], mass: 0.05, pos: [0.3, 0, 0.01]}}")
    assert err.value.message == "env.objects names body 'arm', which model 'yam scene' already has"
    with pytest.raises(LabError) as err:
        lift(1, "env.robot.sites.pinch.body=link_7")
    assert err.value.message.startswith("env.robot.sites' 'pinch' is on body 'link_7', which "
                                        "model 'yam scene' does not have")
