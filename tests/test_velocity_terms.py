"""mjlab's velocity-task terms (the G1 recipe's) against hand-computed cases: a small biped whose
state is set by hand and computed by MuJoCo (`mj_forward`, as after a step), the expected values
with numpy; and every term in a task over Menagerie's G1."""

from __future__ import annotations

import importlib.util
import math

import mujoco
import numpy as np
import pytest
import torch
from conftest import needs_menagerie
from pydantic import ValidationError

from labcli.envs.env import LabVecEnv
from labcli.envs.mdp import config as c
from labcli.envs.mdp.feet import paired_sites
from labcli.envs.mdp.task import RobotTask
from labcli.envs.spec import Menagerie, TaskSpec
from labcli.errors import LabError

# A free base; a torso on a waist joint (about x) with an arm on an unlimited shoulder (about y)
# that hangs beside the base, touching it; two legs (hip, ankle about y) whose feet carry a
# site at their soles. Home: standing, the soles 2 mm into the floor.
BIPED = """
<mujoco model="biped">
  <compiler angle="radian"/>
  <option timestep="0.005"/>
  <worldbody>
    <geom name="floor" type="plane" size="10 10 0.1"/>
    <body name="base" pos="0 0 1">
      <freejoint/>
      <geom type="box" size="0.1 0.15 0.05" mass="10"/>
      <body name="torso" pos="0 0 0.1">
        <joint name="waist" type="hinge" axis="1 0 0" range="-0.5 0.5"/>
        <geom type="box" size="0.08 0.12 0.1" pos="0 0 0.1" mass="5"/>
        <body name="arm" pos="0 0.17 0.1">
          <joint name="shoulder" type="hinge" axis="0 1 0" limited="false"/>
          <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03" mass="1"/>
        </body>
      </body>
      <body name="left_thigh" pos="0 0.08 -0.05">
        <joint name="left_hip" type="hinge" axis="0 1 0" range="-1 1"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.35" size="0.04" mass="2"/>
        <body name="left_foot" pos="0 0 -0.45">
          <joint name="left_ankle" type="hinge" axis="0 1 0" range="-0.6 0.4"/>
          <geom type="box" size="0.08 0.04 0.02" mass="0.5"/>
          <site name="left_sole" pos="0 0 -0.02"/>
        </body>
      </body>
      <body name="right_thigh" pos="0 -0.08 -0.05">
        <joint name="right_hip" type="hinge" axis="0 1 0" range="-1 1"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.35" size="0.04" mass="2"/>
        <body name="right_foot" pos="0 0 -0.45">
          <joint name="right_ankle" type="hinge" axis="0 1 0" range="-0.6 0.4"/>
          <geom type="box" size="0.08 0.04 0.02" mass="0.5"/>
          <site name="right_sole" pos="0 0 -0.02"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="waist"/><motor joint="shoulder"/><motor joint="left_hip"/>
    <motor joint="left_ankle"/><motor joint="right_hip"/><motor joint="right_ankle"/>
  </actuator>
  <keyframe><key name="home" qpos="0 0 0.518 1 0 0 0 0 0 0 0 0 0"/></keyframe>
</mujoco>
"""
JOINTS = ["waist", "shoulder", "left_hip", "left_ankle", "right_hip", "right_ankle"]
STANDING_Z = 0.518
HAVE_WARP = all(importlib.util.find_spec(m) for m in ("warp", "mujoco_warp"))
FEET, SOLES = ["left_foot", "right_foot"], ["left_sole", "right_sole"]


class _Commands(c.Group):
    base_velocity: c.UniformVelocityCommand | None = c.UniformVelocityCommand(
        heading_command=False, rel_standing_envs=0.0)


class _Observations(c.Group):
    joint_pos: c.JointPos | None = c.JointPos()


class _Rewards(c.Group):
    track_linear_velocity: c.TrackLinearVelocity | None = c.TrackLinearVelocity(weight=2.0)
    track_angular_velocity: c.TrackAngularVelocity | None = c.TrackAngularVelocity(weight=2.0)
    upright: c.UprightExp | None = c.UprightExp(weight=1.0, body="torso")
    upright_root: c.UprightExp | None = c.UprightExp(weight=1.0)
    pose: c.VariablePosture | None = c.VariablePosture(
        weight=1.0, std_standing={".*": 0.1}, std_walking={".*_hip": 0.3, ".*": 0.2},
        std_running={".*": 0.5})
    body_ang_vel: c.BodyAngVelXYL2 | None = c.BodyAngVelXYL2(weight=-0.05, body="torso")
    angular_momentum: c.AngularMomentumL2 | None = c.AngularMomentumL2(weight=-0.02)
    dof_pos_limits: c.SoftJointPosLimits | None = c.SoftJointPosLimits(weight=-1.0)
    foot_clearance: c.FeetClearance | None = c.FeetClearance(weight=-2.0, sites=[".*_sole"])
    foot_swing_height: c.FeetSwingHeight | None = c.FeetSwingHeight(
        weight=-0.25, bodies=[".*_foot"], sites=[".*_sole"])
    foot_slip: c.FeetSlip | None = c.FeetSlip(weight=-0.1, bodies=[".*_foot"], sites=[".*_sole"])
    soft_landing: c.SoftLanding | None = c.SoftLanding(weight=-1e-5, bodies=[".*_foot"])
    self_collisions: c.SelfCollisions | None = c.SelfCollisions(weight=-1.0)


class _Biped(c.RobotTaskConfig):
    num_envs: int = 2
    decimation: int = 4
    commands: _Commands = _Commands()
    observations: _Observations = _Observations()
    rewards: _Rewards = _Rewards()


@pytest.fixture(scope="module")
def biped_xml(tmp_path_factory):
    path = tmp_path_factory.mktemp("biped") / "biped.xml"
    path.write_text(BIPED)
    return path


def make(biped_xml, **settings) -> LabVecEnv:
    spec = TaskSpec(name="biped", task=RobotTask, config=_Biped, model=biped_xml)
    env = LabVecEnv(spec, _Biped(**settings))
    env.reset()
    return env


@pytest.fixture
def biped(biped_xml):
    env = make(biped_xml)
    yield env
    env.close()


def term(env, name: str):
    return next(b for b in env.task._rewards if b.name == name)


def value(env, name: str) -> list[float]:
    return term(env, name).compute().tolist()


def pose(env, qpos=None, qvel=None) -> list[mujoco.MjData]:
    """Write the state of every env (`[n, nq]`, `[n, nv]`, or one row for all), let MuJoCo
    compute it as a step ends (`mj_forward`: sensors, contacts and their forces) and hand the
    sensors to the task; MuJoCo's data per env, for the expected values."""
    sim, model = env.sim, env.sim.model
    for state, values in ((sim.qpos, qpos), (sim.qvel, qvel)):
        if values is not None:
            state[:] = torch.as_tensor(np.asarray(values, dtype=float), dtype=state.dtype)
    datas = []
    for i in range(env.num_envs):
        data = mujoco.MjData(model)
        data.qpos[:], data.qvel[:] = sim.qpos[i].numpy(), sim.qvel[i].numpy()
        mujoco.mj_forward(model, data)
        sim.sensordata[i] = torch.from_numpy(data.sensordata.copy())
        datas.append(data)
    env.task.update()
    return datas


def home(**joints: float) -> np.ndarray:
    qpos = np.array([0, 0, STANDING_Z, 1, 0, 0, 0] + [0.0] * len(JOINTS))
    for joint, angle in joints.items():
        qpos[7 + JOINTS.index(joint)] = angle
    return qpos


def command(env, rows) -> None:
    env.task.command("base_velocity").command[:] = torch.as_tensor(rows, dtype=torch.float64)


def quat(axis: str, angle: float) -> list[float]:
    q = [math.cos(angle / 2), 0.0, 0.0, 0.0]
    q[1 + "xyz".index(axis)] = math.sin(angle / 2)
    return q


def rotation(q) -> np.ndarray:
    r = np.zeros(9)
    mujoco.mju_quat2Mat(r, np.asarray(q, dtype=float))
    return r.reshape(3, 3)


def test_tracking_rewards_add_the_velocities_the_command_does_not_ask_for(biped):
    qpos = home()
    qpos[3:7] = quat("z", math.pi / 2)
    lin_w, ang_b = np.array([0.0, 0.8, 0.3]), np.array([0.1, -0.2, 0.2])
    pose(biped, qpos, np.r_[lin_w, ang_b, np.zeros(6)])
    command(biped, [[1.0, 0.0, 0.5], [0.8, 0.0, 0.2]])
    lin_b = rotation(qpos[3:7]).T @ lin_w  # (0.8, 0, 0.3): forward and up
    for i, (cx, cy, cz) in enumerate([[1.0, 0.0, 0.5], [0.8, 0.0, 0.2]]):
        lin_error = (cx - lin_b[0]) ** 2 + (cy - lin_b[1]) ** 2 + lin_b[2] ** 2
        ang_error = (cz - ang_b[2]) ** 2 + ang_b[0] ** 2 + ang_b[1] ** 2
        assert value(biped, "track_linear_velocity")[i] == pytest.approx(
            math.exp(-lin_error / 0.5**2))
        assert value(biped, "track_angular_velocity")[i] == pytest.approx(
            math.exp(-ang_error / 0.5))
    # Env 1 tracks its command exactly, but for the base's z and roll/pitch rates.
    assert value(biped, "track_linear_velocity")[1] == pytest.approx(math.exp(-0.09 / 0.25))


def test_upright_of_a_named_body_and_of_the_root(biped):
    qpos = home(waist=0.3)
    qpos[3:7] = quat("y", 0.2)
    data = pose(biped, qpos)[0]
    for name, body in (("upright", "torso"), ("upright_root", "base")):
        gravity_b = data.xmat[data.body(body).id].reshape(3, 3).T @ [0.0, 0.0, -1.0]
        expected = math.exp(-(gravity_b[0] ** 2 + gravity_b[1] ** 2) / 0.2)
        assert value(biped, name)[0] == pytest.approx(expected)
    # The torso tilts by the base's pitch and the waist's roll; the base by its pitch alone.
    assert value(biped, "upright_root")[0] == pytest.approx(math.exp(-math.sin(0.2) ** 2 / 0.2))
    assert value(biped, "upright")[0] < value(biped, "upright_root")[0]


def test_variable_posture_takes_each_joint_s_std_by_the_command_s_speed(biped):
    offsets = np.array([0.05, -0.1, 0.2, 0.03, -0.15, 0.0])
    pose(biped, home(**dict(zip(JOINTS, offsets, strict=True))))
    stds = {"standing": [0.1] * 6, "walking": [0.2, 0.2, 0.3, 0.2, 0.3, 0.2],
            "running": [0.5] * 6}

    def expected(regime: str) -> float:
        return math.exp(-np.mean((offsets / np.array(stds[regime])) ** 2))

    # |lin xy| + |yaw rate|: below 0.05 standing, 0.05 up to 1.5 walking, from 1.5 running.
    for rows, regimes in (([[0.0, 0.0, 0.04], [0.05, 0.0, 0.0]], ["standing", "walking"]),
                          ([[0.6, 0.8, -0.49], [0.6, 0.8, 0.5]], ["walking", "running"])):
        command(biped, rows)
        biped.task.update()
        assert value(biped, "pose") == pytest.approx([expected(r) for r in regimes])


def test_a_joint_no_posture_pattern_names_is_one_line(biped_xml):
    rewards = _Rewards(pose=c.VariablePosture(weight=1.0, std_standing={".*": 0.1},
                                              std_walking={".*_hip": 0.3, ".*_ankle": 0.2},
                                              std_running={".*": 0.5}))
    with pytest.raises(LabError) as error:
        make(biped_xml, rewards=rewards)
    assert "joint 'waist' matches none of std_walking's patterns" in str(error.value)
    assert "\n" not in str(error.value)
    with pytest.raises(ValidationError, match="not a regular expression"):
        c.VariablePosture(weight=1.0, std_standing={"(": 0.1}, std_walking={".*": 0.1},
                          std_running={".*": 0.1})


def body_velocity(data: mujoco.MjData, body: int) -> tuple[np.ndarray, np.ndarray]:
    """A body's angular velocity and its center of mass's linear velocity, world frame."""
    v = np.zeros(6)
    mujoco.mj_objectVelocity(data.model, data, mujoco.mjtObj.mjOBJ_BODY, body, v, 0)
    return v[:3], v[3:]


def test_body_angular_velocity_and_the_robot_s_angular_momentum(biped):
    qpos = home(waist=0.2, left_hip=0.4)
    qpos[3:7] = quat("z", 0.7)
    qvel = np.array([0.3, -0.2, 0.1, 0.5, -0.4, 0.9, 1.5, -2.0, 0.7, 0.3, -0.6, 0.2])
    data = pose(biped, qpos, qvel)[0]
    model = data.model
    # The torso turns with the base (its angular velocity is in its own frame) and the waist
    # (about x, the base's x axis too).
    torso_w = rotation(qpos[3:7]) @ (qvel[3:6] + [qvel[6], 0.0, 0.0])
    assert value(biped, "body_ang_vel")[0] == pytest.approx(torso_w[0] ** 2 + torso_w[1] ** 2)
    # About the center of mass: each body's spin (its inertia turned into the world) and its
    # center of mass's motion about the whole's.
    bodies = range(1, model.nbody)
    mass = sum(model.body_mass[b] for b in bodies)
    com = sum(model.body_mass[b] * data.xipos[b] for b in bodies) / mass
    momentum = np.zeros(3)
    for b in bodies:
        omega, v = body_velocity(data, b)
        r = data.ximat[b].reshape(3, 3)
        momentum += r @ np.diag(model.body_inertia[b]) @ r.T @ omega
        momentum += model.body_mass[b] * np.cross(data.xipos[b] - com, v)
    assert value(biped, "angular_momentum")[0] == pytest.approx(momentum @ momentum, rel=1e-6)
    assert momentum @ momentum > 0.1


def test_soft_joint_limits_are_the_range_shrunk_about_its_middle(biped):
    model = biped.sim.model
    angles = {"waist": 0.5, "shoulder": 100.0, "left_hip": -0.95, "left_ankle": 0.38,
              "right_hip": 0.89}
    pose(biped, np.stack([home(**angles), home()]))
    expected = 0.0
    for joint, q in angles.items():
        if model.joint(joint).limited[0]:
            low, high = model.joint(joint).range
            middle, half = (low + high) / 2, (high - low) / 2 * 0.9
            expected += max(middle - half - q, 0.0) + max(q - middle - half, 0.0)
    # waist 0.05 past 0.45, left hip 0.05 past -0.9, left ankle 0.03 past 0.35; the shoulder
    # has no limits, the right hip is inside.
    assert expected == pytest.approx(0.13)
    assert value(biped, "dof_pos_limits") == pytest.approx([expected, 0.0])


def feet_forces(data: mujoco.MjData) -> np.ndarray:
    """The net force of each foot's contacts with the floor (world frame), `[feet, 3]`."""
    model, out = data.model, np.zeros((2, 3))
    for i, contact in enumerate(data.contact[:data.ncon]):
        bodies = {int(model.geom_bodyid[g]) for g in contact.geom}
        for k, foot in enumerate(FEET):
            if bodies == {0, model.body(foot).id}:
                f = np.zeros(6)
                mujoco.mj_contactForce(model, data, i, f)
                out[k] += contact.frame.reshape(3, 3).T @ f[:3]
    return out


def test_foot_terms_from_contacts_and_sole_sites(biped):
    # Env 0 stands on both feet; env 1's left leg swings forward, its foot off the floor. Both
    # slide along x at 0.4 m/s, and env 0's base turns about z.
    qvel = np.zeros((2, 12))
    qvel[:, 0], qvel[0, 5] = 0.4, 0.5
    datas = pose(biped, np.stack([home(), home(left_hip=0.6)]), qvel)
    command(biped, [[0.5, 0.0, 0.0], [0.03, 0.0, 0.01]])  # env 1 under the threshold
    contacts = term(biped, "foot_slip").made.contacts
    assert contacts.touching().tolist() == [[True, True], [False, True]]
    forces = np.stack([feet_forces(d) for d in datas])
    assert np.linalg.norm(forces[0], axis=1).min() > 10.0  # the feet carry the robot
    assert contacts.force_norm().numpy() == pytest.approx(np.linalg.norm(forces, axis=2))

    sites = [d.site_xpos[[d.model.site(s).id for s in SOLES]] for d in datas]
    speeds = []
    for d in datas:
        v = np.zeros((2, 6))
        for k, s in enumerate(SOLES):
            mujoco.mj_objectVelocity(d.model, d, mujoco.mjtObj.mjOBJ_SITE, d.model.site(s).id,
                                     v[k], 0)
        speeds.append(np.linalg.norm(v[:, 3:5], axis=1))
    assert speeds[0][0] != pytest.approx(0.4)  # the turn moves the soles too
    clearance = [float(np.sum(np.abs(sites[i][:, 2] - 0.1) * speeds[i])) for i in range(2)]
    slip = [float(np.sum(speeds[0] ** 2)), 0.0]
    assert value(biped, "foot_clearance") == pytest.approx([clearance[0], 0.0])
    assert value(biped, "foot_slip") == pytest.approx(slip)
    # A reset leaves no foot touching: standing feet make their first contact in the first step.
    landing = np.linalg.norm(forces[0], axis=1).sum()
    assert value(biped, "soft_landing") == pytest.approx([landing, 0.0])
    command(biped, [[0.5, 0.0, 0.0], [0.3, 0.0, 0.0]])
    biped.task.update()
    assert value(biped, "foot_clearance")[1] == pytest.approx(clearance[1])
    assert value(biped, "foot_slip")[1] == pytest.approx(speeds[1][1] ** 2)
    assert value(biped, "soft_landing")[1] == pytest.approx(np.linalg.norm(forces[1, 1]))
    biped.task.after_step()
    biped.task.update()  # the next step's state: the same
    assert value(biped, "soft_landing") == [0.0, 0.0]  # still standing: no new contact
    # Two steps of 0.02 s in the air: the last and this one.
    assert contacts.air_time().numpy() == pytest.approx(np.array([[0.0, 0.0], [0.04, 0.0]]))


def test_feet_swing_height_costs_the_peak_at_landing(biped):
    swing = term(biped, "foot_swing_height")
    command(biped, [[0.5, 0.0, 0.0], [0.5, 0.0, 0.0]])

    def step(left_hip: float) -> tuple[list[float], float]:
        data = pose(biped, home(left_hip=left_hip))[0]
        cost = swing.compute().tolist()
        biped.task.after_step()
        biped.task.robot.forget_derived()  # as the next step does
        return cost, float(data.site_xpos[data.model.site("left_sole").id][2])

    assert step(0.0)[0] == pytest.approx([2.0, 2.0])  # first contacts at a peak of 0
    heights = []
    for angle in (0.3, 0.7, 0.5):  # the left foot swings in the air
        cost, height = step(angle)
        assert cost == [0.0, 0.0]
        heights.append(height)
    assert max(heights) > 0.05
    cost, _ = step(0.0)  # and lands
    assert cost == pytest.approx([(max(heights) / 0.1 - 1.0) ** 2] * 2)
    assert swing.made.peak.tolist() == [[0.0, 0.0], [0.0, 0.0]]
    step(0.7)
    assert swing.made.peak[:, 0].tolist() == pytest.approx([max(heights)] * 2)
    biped.task.reset(torch.tensor([True, False]), biped.rng)
    assert swing.made.peak[:, 0].tolist() == pytest.approx([0.0, max(heights)])


def test_self_collisions_count_the_robot_s_own_contacts_over_the_threshold(biped):
    datas = pose(biped, np.stack([home(), home(shoulder=math.pi / 2)]))
    model = biped.sim.model
    robot = {b for b in range(model.nbody) if b > 0}
    expected = []
    for data in datas:
        count = 0
        for i, contact in enumerate(data.contact[:data.ncon]):
            if {int(model.geom_bodyid[g]) for g in contact.geom} <= robot:
                f = np.zeros(6)
                mujoco.mj_contactForce(model, data, i, f)
                count += np.linalg.norm(f[:3]) > 10.0
        expected.append(float(count))
    # The hanging arm presses on the base; raised, it touches nothing.
    assert expected[0] >= 1 and expected[1] == 0
    assert value(biped, "self_collisions") == expected


def test_feet_pair_with_the_site_on_each(biped):
    model = biped.sim.model
    assert paired_sites(model, ["right_foot", "left_foot"], [".*_sole"]) == [
        "right_sole", "left_sole"]
    with pytest.raises(LabError, match="foot 'left_foot' has 0 of the sites"):
        paired_sites(model, FEET, ["right_sole"])


def test_forward_only_commands(biped_xml):
    every = c.UniformVelocityCommand(heading_command=False, rel_standing_envs=0.0,
                                     rel_forward_envs=1.0)
    env = make(biped_xml, num_envs=64, commands=_Commands(base_velocity=every))
    cmd = env.task.command("base_velocity")
    assert cmd.forward_env.all()
    assert (cmd.command[:, 0] >= 0.3).all() and (cmd.command[:, 1:] == 0).all()
    assert (cmd.command[:, 0] > 0.3).any()  # |lin x| where it was faster
    env.close()
    half = every.model_copy(update={"rel_forward_envs": 0.5})
    env = make(biped_xml, num_envs=64, commands=_Commands(base_velocity=half))
    cmd = env.task.command("base_velocity")
    assert 0.25 < cmd.forward_env.float().mean() < 0.75
    assert (cmd.command[~cmd.forward_env, 1] != 0).all()
    env.close()
    env = make(biped_xml, num_envs=4)
    cmd = env.task.command("base_velocity")
    # By default none, and the draws are those made before forward-only commands existed.
    assert not cmd.forward_env.any() and cmd.draw.sample.shape == (4, 7)
    env.close()


class _G1Rewards(c.Group):
    track_linear_velocity: c.TrackLinearVelocity | None = c.TrackLinearVelocity(weight=2.0)
    track_angular_velocity: c.TrackAngularVelocity | None = c.TrackAngularVelocity(weight=2.0)
    upright: c.UprightExp | None = c.UprightExp(weight=1.0, body="torso_link")
    pose: c.VariablePosture | None = c.VariablePosture(
        weight=1.0, std_standing={".*": 0.05},
        std_walking={".*hip_pitch.*": 0.3, ".*knee.*": 0.35, ".*": 0.15},
        std_running={".*hip_pitch.*": 0.5, ".*knee.*": 0.6, ".*": 0.3})
    body_ang_vel: c.BodyAngVelXYL2 | None = c.BodyAngVelXYL2(weight=-0.05, body="torso_link")
    angular_momentum: c.AngularMomentumL2 | None = c.AngularMomentumL2(weight=-0.02)
    dof_pos_limits: c.SoftJointPosLimits | None = c.SoftJointPosLimits(weight=-1.0)
    foot_clearance: c.FeetClearance | None = c.FeetClearance(
        weight=-2.0, sites=["left_foot", "right_foot"])
    foot_swing_height: c.FeetSwingHeight | None = c.FeetSwingHeight(
        weight=-0.25, bodies=["left_ankle_roll_link", "right_ankle_roll_link"],
        sites=["left_foot", "right_foot"])
    foot_slip: c.FeetSlip | None = c.FeetSlip(
        weight=-0.1, bodies=["left_ankle_roll_link", "right_ankle_roll_link"],
        sites=["left_foot", "right_foot"])
    soft_landing: c.SoftLanding | None = c.SoftLanding(
        weight=-1e-5, bodies=["left_ankle_roll_link", "right_ankle_roll_link"])
    self_collisions: c.SelfCollisions | None = c.SelfCollisions(weight=-1.0)


class _G1(c.RobotTaskConfig):
    num_envs: int = 2
    decimation: int = 4
    sim_dt: float | None = 0.005
    nconmax: int | None = 35  # mjlab's, per world (warp)
    njmax: int | None = 300
    actions: c.JointPosition = c.JointPosition(scale=0.25)
    commands: _Commands = _Commands()
    observations: _Observations = _Observations()
    rewards: _G1Rewards = _G1Rewards()


@needs_menagerie("unitree_g1")
def test_every_term_in_a_task_over_menagerie_s_g1():
    spec = TaskSpec(name="g1-terms", task=RobotTask, config=_G1,
                    model=Menagerie("unitree_g1", "scene_mjx"))
    env = LabVecEnv(spec, _G1())
    env.reset()
    model = env.sim.model
    assert model.sensor("lab:subtreeangmom:pelvis").dim[0] == 3
    # One contact sensor per foot, shared by the three terms that read the feet's contacts.
    assert sum(model.sensor(i).name.startswith("lab:contact:subtree:") for i in
               range(model.nsensor)) == 2
    command(env, [[0.5, 0.0, 0.2], [0.0, 0.0, 0.0]])
    hold = torch.zeros(2, model.nu)
    for _ in range(25):  # 0.5 s holding the home pose
        env.step(hold)
    assert torch.isfinite(env.episode_terms).all()
    terms = {b.name: b.compute() for b in env.task._rewards}
    assert all(torch.isfinite(t).all() and t.shape == (2,) for t in terms.values())
    contacts = next(b for b in env.task._rewards if b.name == "foot_slip").made.contacts
    assert contacts.touching().all()  # standing on both feet
    forces = contacts.force_norm().sum(dim=1)
    weight = float(model.body_subtreemass[model.body("pelvis").id]) * 9.81
    assert forces.tolist() == pytest.approx([weight] * 2, rel=0.1)
    assert terms["upright"].min() > 0.9  # the torso leans a little, held by the PD alone
    # The same pose (both envs hold the default one alike), tighter for the envs standing.
    assert 0.0 < terms["pose"][1] < terms["pose"][0] <= 1.0
    assert terms["self_collisions"].tolist() == [0.0, 0.0]
    assert terms["soft_landing"].tolist() == [0.0, 0.0]  # no new contact while standing
    env.close()


@pytest.mark.gpu
@pytest.mark.skipif(not (HAVE_WARP and torch.cuda.is_available()),
                    reason='needs a CUDA GPU and MuJoCo Warp (pip install -e ".[warp]")')
@needs_menagerie("unitree_g1")
def test_both_backends_read_the_same_terms_on_the_g1():
    """The G1 holding its home pose for 0.5 s on both backends (warp: one CUDA graph a step),
    from the same reset and commands: every term, and the feet's contacts, alike."""
    spec = TaskSpec(name="g1-terms", task=RobotTask, config=_G1,
                    model=Menagerie("unitree_g1", "scene_mjx"))
    envs = [LabVecEnv(spec, _G1(), backend=backend, device=device, seed=0)
            for backend, device in (("cpu", "cpu"), ("warp", "cuda"))]
    seen = []
    for env in envs:
        env.reset()
        command(env, [[0.5, 0.0, 0.2], [0.0, 0.0, 0.0]])
        hold = torch.zeros(2, env.sim.model.nu, device=env.device)
        for _ in range(25):
            env.step(hold)
        contacts = next(b for b in env.task._rewards if b.name == "foot_slip").made.contacts
        seen.append(({b.name: b.compute().double().cpu() for b in env.task._rewards},
                     contacts.touching().cpu(), contacts.force_norm().double().cpu()))
        env.close()
    (cpu, cpu_touching, cpu_force), (gpu, gpu_touching, gpu_force) = seen
    assert torch.equal(cpu_touching, gpu_touching) and cpu_touching.all()
    assert gpu_force.numpy() == pytest.approx(cpu_force.numpy(), rel=0.1)
    for name in ("track_linear_velocity", "track_angular_velocity", "upright", "pose",
                 "dof_pos_limits"):
        assert gpu[name].numpy() == pytest.approx(cpu[name].numpy(), rel=0.02, abs=1e-3), name
    for name in ("body_ang_vel", "angular_momentum", "foot_clearance", "foot_slip"):
        assert gpu[name].numpy() == pytest.approx(cpu[name].numpy(), abs=0.02), name
    for name in ("foot_swing_height", "soft_landing", "self_collisions"):
        assert gpu[name].tolist() == cpu[name].tolist() == [0.0, 0.0], name
