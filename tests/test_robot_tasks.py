"""Robot-task building blocks (labcli/envs/mdp) against hand-computed cases, and the ant and
humanoid tasks built from them, on the real models at small sizes."""

from __future__ import annotations

import importlib.util
import math

import mujoco
import pytest
import torch
from backends import lift_and_copy, worst_gaps
from conftest import needs_menagerie
from lab_locomotion.config import AntConfig, AntObservations, AntTerminations, LocomotionEvents
from lab_locomotion.plugin import HERE
from oneline import assert_one_line_error
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.envs.env import LabVecEnv
from labcli.envs.mdp import config as c
from labcli.envs.mdp import names, sensors
from labcli.envs.mdp.task import RobotTask
from labcli.envs.spec import TaskSpec
from labcli.errors import LabError
from labcli.gym import make_env

DT = 2 / 120  # ant and humanoid: 120 Hz physics, decimation 2
ANT_MODEL = HERE / "ant.xml"
HAVE_WARP = all(importlib.util.find_spec(m) for m in ("warp", "mujoco_warp"))


def lab(*args: str, logs):
    return CliRunner().invoke(app, list(args), env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "300"})


@pytest.fixture
def ant():
    env = make_env("ant", num_envs=4, seed=0)
    env.reset()
    yield env
    env.close()


def put(env, root_pos=None, root_quat=None, lin_vel=None, ang_vel=None) -> None:
    """Write the root state of every env, then let the task recompute what it derives."""
    r = env.task.robot
    for view, value in ((r.root_pos, root_pos), (r.root_quat, root_quat),
                        (r.root_lin_vel_w, lin_vel), (r.root_ang_vel_b, ang_vel)):
        if value is not None:
            view[:] = torch.as_tensor(value, dtype=view.dtype)
    env.task.update()


def obs(env, name: str) -> torch.Tensor:
    """The columns of observation term `name` (unscaled: looked up by name, then divided)."""
    columns = [i for i, n in enumerate(env.observation_names)
               if n == name or n.startswith(name + ".") or n.startswith(name + "[")]
    scale = getattr(env.cfg.observations, name).scale
    return env.observations()[:, columns] / scale


YAW_90 = [math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]  # +90° about z
ROLL_90 = [math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0]  # +90° about x


def test_body_frame_velocities_gravity_and_angles(ant):
    put(ant, root_pos=[0.0, 0.0, 0.5], root_quat=YAW_90, lin_vel=[1.0, 0.0, 0.0],
        ang_vel=[0.0, 0.0, 2.0])
    # Facing +y, moving along +x: to its right, i.e. -y in its own frame.
    assert obs(ant, "base_lin_vel")[0].tolist() == pytest.approx([0.0, -1.0, 0.0], abs=1e-6)
    assert obs(ant, "base_ang_vel")[0].tolist() == pytest.approx([0.0, 0.0, 2.0])
    assert obs(ant, "base_height")[0].item() == pytest.approx(0.5)
    yaw, roll = obs(ant, "base_yaw_roll")[0].tolist()
    assert (yaw, roll) == pytest.approx((math.pi / 2, 0.0), abs=1e-6)
    # The target is 1 km along +x: 90° to the right, and the heading is orthogonal to it.
    assert obs(ant, "base_angle_to_target")[0].item() == pytest.approx(-math.pi / 2, abs=1e-3)
    assert obs(ant, "base_heading_proj")[0].item() == pytest.approx(0.0, abs=1e-3)
    assert obs(ant, "base_up_proj")[0].item() == pytest.approx(1.0)

    put(ant, root_quat=ROLL_90)
    gravity = ant.task.robot.projected_gravity_b[0].tolist()
    # Rolled +90° about x, the body's y axis points up: gravity (down) is -y in its frame.
    assert gravity == pytest.approx([0.0, -1.0, 0.0], abs=1e-6)
    assert obs(ant, "base_up_proj")[0].item() == pytest.approx(0.0, abs=1e-6)
    assert obs(ant, "base_yaw_roll")[0].tolist() == pytest.approx([0.0, math.pi / 2], abs=1e-6)


def test_joint_positions_normalized_to_their_limits(ant):
    r = ant.task.robot
    r.joint_pos[:] = r.joint_lower
    r.joint_pos[0] = r.joint_upper[0]
    ant.task.update()
    normalized = obs(ant, "joint_pos_norm")
    assert normalized[0].tolist() == pytest.approx([1.0] * 8)
    assert normalized[1].tolist() == pytest.approx([-1.0] * 8)


def test_progress_is_the_step_s_approach_to_the_target_over_dt(ant):
    put(ant, root_pos=[0.0, 0.0, 0.5], root_quat=[1, 0, 0, 0], lin_vel=[0, 0, 0])
    progress = ant.task._rewards[0]
    assert progress.name == "progress"
    progress.pre_physics()
    put(ant, root_pos=[0.03, 0.0, 0.5])  # 3 cm closer to (1000, 0)
    assert progress.compute()[0].item() == pytest.approx(0.03 / DT, rel=1e-4)


def test_heading_bonus_energy_and_joint_limit_penalty_by_hand(ant):
    put(ant, root_pos=[0.0, 0.0, 0.5], root_quat=[1, 0, 0, 0])
    terms = {b.name: b for b in ant.task._rewards}
    assert terms["move_to_target"].compute()[0].item() == pytest.approx(1.0)  # facing it
    assert terms["upright"].compute()[0].item() == 1.0
    assert terms["alive"].compute()[0].item() == 1.0
    half = [math.cos(math.pi / 6), 0.0, 0.0, math.sin(math.pi / 6)]  # yaw 60°: cos 0.5
    put(ant, root_quat=half)
    assert terms["move_to_target"].compute()[0].item() == pytest.approx(0.5 / 0.8, rel=1e-4)

    r = ant.task.robot
    ant.task.action[:] = 0.5
    r.joint_vel[:] = 2.0
    ant.task.update()
    assert terms["energy"].compute()[0].item() == pytest.approx(8 * 0.5 * 2.0)  # equal gears
    assert terms["action_l2"].compute()[0].item() == pytest.approx(8 * 0.25)
    # Joint 0 at 99.5% of its half-range from the middle: half way past the 0.99 threshold.
    middle, half_range = (r.joint_upper + r.joint_lower) / 2, (r.joint_upper - r.joint_lower) / 2
    r.joint_pos[:] = middle
    r.joint_pos[:, 0] = middle[:, 0] + 0.995 * half_range[:, 0]
    ant.task.update()
    assert terms["joint_pos_limits"].compute()[0].item() == pytest.approx(0.5, rel=1e-4)


def test_terminations_and_success(ant):
    put(ant, root_pos=[0.0, 0.0, 0.30], root_quat=[1, 0, 0, 0])
    assert ant.task.terminations()["torso_height"].all()
    put(ant, root_pos=[0.0, 0.0, 0.40])
    assert not ant.task.terminations()["torso_height"].any()
    mask = torch.ones(4, dtype=torch.bool)
    ant.task._success.reset(mask)  # the episode starts here
    put(ant, root_pos=[7.9, 0.0, 0.5])
    assert not ant.task.success(mask).any()
    put(ant, root_pos=[8.1, 3.0, 0.5])  # 8.1 m toward the target, sideways does not count
    assert ant.task.success(mask).all()


class _Observations(AntObservations):
    feet_contact: c.ContactForces | None = c.ContactForces(bodies=[".*_foot"])


class _Terminations(AntTerminations):
    torso_contact: c.IllegalContact | None = c.IllegalContact(bodies=["torso"])


class _AntWithContacts(AntConfig):
    observations: _Observations = _Observations()
    terminations: _Terminations = _Terminations()


def test_feet_carry_the_ant_s_weight_through_contact_sensors():
    spec = TaskSpec(name="ant", task=RobotTask, config=_AntWithContacts, model=ANT_MODEL)
    env = LabVecEnv(spec, _AntWithContacts(num_envs=2, events={"reset_base": None,
                                                               "reset_robot_joints": None}))
    env.reset()
    zero = torch.zeros(2, 8)
    for _ in range(60):  # 1 s: it settles on its feet
        env.step(zero)
    forces = obs(env, "feet_contact").view(2, 4, 3)
    mass = float(env.sim.model.body_subtreemass[env.task.robot.root_body])
    assert forces[:, :, 2].sum(dim=1).abs().tolist() == pytest.approx([mass * 9.81] * 2,
                                                                      rel=0.02)
    assert not env.task.terminations()["torso_contact"].any()
    put(env, root_pos=[0.0, 0.0, 0.24], root_quat=[0.0, 1.0, 0.0, 0.0])  # on its back
    env.sim.step(1)
    env.task.update()
    assert env.task.terminations()["torso_contact"].all()
    env.close()


def test_bad_names_ranges_and_terms_are_one_line_errors(tmp_path):
    cases = [
        (["--set", "env.observations.feet_body_forces.bodies=[front_left_fot]"],
         ["model 'ant' has no body named 'front_left_fot'", "front_left_foot"]),
        (["--set", "env.rewards.bogus={weight: 1.0}"], ["env.rewards.bogus"]),
        (["--set", "env.events.reset_robot_joints.position_range=[0.2,-0.2]"],
         ["position_range is (0.2, -0.2)", "(low, high)"]),
        (["--set", "env.reward_weights={alive: 1.0}"], ["env.rewards.<term>.weight"]),
    ]
    for args, phrases in cases:
        result = lab("train", "--task", "ant", "--framework", "rsl_rl", "--num-envs", "2",
                     "--max-iterations", "1", *args, logs=tmp_path / "logs")
        assert_one_line_error(result, *phrases)
    assert not (tmp_path / "logs").exists() or not any((tmp_path / "logs").rglob("*.json"))


def test_resolve_names_patterns_and_closest():
    model = mujoco.MjModel.from_xml_path(str(ANT_MODEL))
    bodies = names.all_names(model, "body")
    feet = [bodies[i] for i in names.resolve(model, "body", [".*_foot"])]
    assert feet == ["front_left_foot", "front_right_foot", "left_back_foot", "right_back_foot"]
    with pytest.raises(LabError) as err:
        names.resolve(model, "joint", ["front_left_lge"])
    assert "has no joint named 'front_left_lge'" in str(err.value)
    assert "front_left_leg" in err.value.hint


def test_range_low_above_high_is_refused_by_the_config():
    with pytest.raises(ValueError, match="low end is above"):
        c.ResetJointsByOffset(position_range=(0.2, -0.2))
    with pytest.raises(ValueError, match="keys are"):
        c.ResetRootUniform(pose_range={"height": (0.0, 1.0)})



@pytest.mark.gpu
@pytest.mark.skipif(not (HAVE_WARP and torch.cuda.is_available()),
                    reason='needs a CUDA GPU and MuJoCo Warp (pip install -e ".[warp]")')
@pytest.mark.parametrize("task", ["ant", "humanoid"])
def test_both_backends_agree_on_a_short_rollout(task):
    """From the same state, with the same actions, 10 env steps on MuJoCo's C engine (float64)
    and on MuJoCo Warp (float32, in a CUDA graph) give the same observations and rewards. In
    the air (1 m up): contacts make the two diverge within a few steps (float32 against
    float64, and MuJoCo Warp's solver settings); the feet carrying the weight on both backends
    is the contact test (test_per_env_mass_...)."""
    cpu = make_env(task, num_envs=8, backend="cpu", device="cpu", seed=0,
                   overrides=["env.observation_noise=false"])
    gpu = make_env(task, num_envs=8, backend="warp", device="cuda", seed=0,
                   overrides=["env.observation_noise=false"])
    cpu.reset(), gpu.reset()
    lift_and_copy(cpu, gpu)
    worst_obs, worst_reward = worst_gaps(cpu, gpu)
    cpu.close(), gpu.close()
    assert worst_obs < 0.05 and worst_reward < 0.05, (worst_obs, worst_reward)


class _HeavyEvents(LocomotionEvents):
    heavier: c.RandomizeMass | None = c.RandomizeMass(bodies=["torso"], mass_range=(1.0, 3.0))
    grip: c.RandomizeFriction | None = c.RandomizeFriction(friction_range=(0.4, 1.2),
                                                           mode="reset")


class _HeavyAnt(_AntWithContacts):
    events: _HeavyEvents = _HeavyEvents(reset_base=None, reset_robot_joints=None)


BACKENDS = ["cpu", pytest.param("warp", marks=[pytest.mark.gpu, pytest.mark.skipif(
    not (HAVE_WARP and torch.cuda.is_available()), reason="needs a CUDA GPU and MuJoCo Warp"
)])]


@pytest.mark.parametrize("backend", BACKENDS)
def test_per_env_mass_and_friction_change_the_physics_of_each_env(backend):
    spec = TaskSpec(name="ant", task=RobotTask, config=_HeavyAnt, model=ANT_MODEL)
    device = "cuda" if backend == "warp" else "cpu"
    env = LabVecEnv(spec, _HeavyAnt(num_envs=3), backend=backend, device=device, seed=0)
    env.reset()
    base = float(mujoco.MjModel.from_xml_path(str(ANT_MODEL)).body("torso").mass[0])
    added = env.sim.model_field("body_mass")[:, 1] - base
    assert ((added >= 1.0) & (added <= 3.0)).all() and len(set(added.tolist())) == 3
    friction = env.sim.model_field("geom_friction")[:, :, 0]
    robot = friction[:, 1:]  # geom 0 is the floor's, left alone
    assert ((robot >= 0.4) & (robot <= 1.2)).all() and (friction[:, 0] == 1.0).all()
    friction[:] = 1.0  # the floor's: the weight below needs the ant settled on all its feet
    env.sim.model_changed("geom_friction", torch.ones(3, dtype=torch.bool, device=device))
    feet = torch.zeros(3, dtype=torch.float64)
    for step in range(90):
        env.step(torch.zeros(3, 8, device=device))
        if step >= 60:  # settled: the mean of the last 0.5 s
            feet += obs(env, "feet_contact").view(3, 4, 3)[:, :, 2].sum(dim=1).abs().cpu() / 30
    # Each env's own model steps it: its feet carry its own weight. On MuJoCo Warp (float32,
    # its solver's looser tolerance) an H100 measured envs 0 and 1 within 2% and env 2 9% above
    # its weight: what holds there is that every env carries its own, in the order of its mass.
    weight = (float(env.sim.model.body_subtreemass[1]) + added.cpu().double()) * 9.81
    assert feet.argsort().tolist() == weight.argsort().tolist()
    assert feet.tolist() == pytest.approx(weight.tolist(), rel=0.02 if backend == "cpu" else 0.1)
    env.close()


@pytest.mark.gpu
@pytest.mark.skipif(not (HAVE_WARP and torch.cuda.is_available()),
                    reason='needs a CUDA GPU and MuJoCo Warp (pip install -e ".[warp]")')
def test_a_contact_buffer_overflow_is_counted_by_name_and_its_envs_reset():
    env = make_env("ant", num_envs=8, backend="warp", device="cuda", seed=0,
                   overrides=["env.nconmax=1", "env.njmax=8"])
    env.reset()
    for _ in range(30):  # standing on four feet: 4 contacts, 16+ rows per env
        env.step(torch.zeros(8, 8, device="cuda"))
    stats = env.pop_stats()
    env.close()
    overflows = {k: v for k, v in stats.items() if k.startswith("sim/overflow/")}
    assert overflows and all(v > 0 for v in overflows.values()), stats
    assert stats.get("sim/instabilities", 0) > 0


def test_play_turns_observation_noise_off_unless_asked_and_sets_nothing_else(tmp_path):
    logs = tmp_path / "logs"
    trained = lab("train", "--task", "ant", "--framework", "rsl_rl", "--num-envs", "4",
                  "--max-iterations", "1", "--set", "agent.num_steps_per_env=4",
                  "--set", "agent.actor_hidden_dims=[8]", "--set", "agent.critic_hidden_dims=[8]",
                  logs=logs)
    assert trained.exit_code == 0, trained.output
    run = next(logs.glob("rsl_rl/ant/*"))
    assert "observation_noise: true" in (run / "params" / "env.yaml").read_text()
    for extra in ([], ["--set", "env.observation_noise=true"]):
        played = lab("play", "--last", "--task", "ant", "--episodes", "1", *extra, logs=logs)
        assert played.exit_code == 0 and "1 episodes" in played.stdout, played.output
    from labcli.runs.play import load

    for overrides, noise in (((), False), (("env.observation_noise=true",), True)):
        loaded = load(run_dir=run, overrides=overrides)
        assert loaded.env.cfg.observation_noise is noise
        loaded.env.close()
    refused = lab("play", "--last", "--task", "ant", "--set", "env.num_envs=3", logs=logs)
    assert_one_line_error(refused, "--set env.num_envs cannot change a run",
                          "env.observation_noise")


@pytest.mark.parametrize("task", ["humanoid", pytest.param("go1-flat", marks=needs_menagerie(
    "unitree_go1"))])
def test_the_thread_count_does_not_change_a_robot_tasks_trajectory(task):
    """Contacts, sensors, per-env models (go1-flat's friction and mass) and resets: the same
    outputs bit for bit on one thread, on two (the calling thread and a worker) and on MuJoCo's
    pool (3)."""
    gen = torch.Generator().manual_seed(0)
    actions = None
    runs = []
    for threads in (1, 2, 3):
        env = make_env(task, num_envs=6, seed=1, threads=threads, episode_length_s=0.3)
        assert env.sim.nthread == threads
        if actions is None:
            shape = (25, *env.action_space.shape)
            actions = torch.rand(shape, generator=gen) * 2 - 1
        outputs = [env.reset(seed=1)[0]]
        for action in actions:
            obs, reward, terminated, truncated, info = env.step(action)
            outputs += [obs, reward, terminated, truncated, info["final_obs"]]
        env.close()
        runs.append(outputs)
    assert runs[0][-1].ne(runs[0][1]).any()  # it moved, so the comparison means something
    assert any(out.any() for out in runs[0][4::5])  # episodes ended and were reset
    for other in runs[1:]:
        for mine, theirs in zip(runs[0], other, strict=True):
            torch.testing.assert_close(theirs, mine, rtol=0, atol=0, equal_nan=True)


@needs_menagerie("unitree_go1")
def test_the_config_sets_the_physics_options_over_the_model_s():
    """go1-flat sets the step and the solver's iterations; cones, impratio and the integrator
    stay Menagerie's (elliptic, 100, and MuJoCo's Euler: the Go1's MJCF names none) unless set:
    pyramidal cones step a Go1 2.3x as fast on the CPU."""
    from labcli.gym import make_env

    env = make_env("go1-flat", num_envs=2, backend="cpu")
    opt = env.sim.model.opt
    assert (opt.timestep, opt.iterations, opt.ls_iterations) == (0.005, 10, 20)
    assert (opt.cone, opt.impratio) == (mujoco.mjtCone.mjCONE_ELLIPTIC, 100.0)
    assert opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    env.close()
    env = make_env("go1-flat", num_envs=2, backend="cpu", overrides=[
        "env.cone=pyramidal", "env.impratio=1", "env.integrator=implicitfast"])
    opt = env.sim.model.opt
    assert (opt.cone, opt.impratio, opt.integrator) == (
        mujoco.mjtCone.mjCONE_PYRAMIDAL, 1.0, mujoco.mjtIntegrator.mjINT_IMPLICITFAST)
    env.step(torch.zeros(2, 12))
    env.close()
    with pytest.raises(LabError, match="cone"):
        make_env("go1-flat", num_envs=2, backend="cpu", overrides=["env.cone=round"])
    with pytest.raises(LabError, match="integrator"):
        make_env("go1-flat", num_envs=2, backend="cpu", overrides=["env.integrator=implicit"])


def test_a_term_reading_the_contacts_of_a_body_that_touches_nothing_is_refused():
    """A contact sensor on a body whose geoms collide with nothing reads zeros forever: a
    termination that never ends an episode, a penalty never paid."""
    model = mujoco.MjModel.from_xml_string("""<mujoco><worldbody>
        <geom name="floor" type="plane" size="1 1 0.1"/>
        <body name="paired"><freejoint/><geom name="pad" size="0.1" contype="0" conaffinity="0"/>
          <body name="child" pos="0 0 0.3"><geom size="0.05" contype="0" conaffinity="0"/></body>
        </body>
        <body name="colliding" pos="1 0 0"><freejoint/><geom size="0.1"/></body>
        </worldbody><contact><pair geom1="pad" geom2="floor"/></contact></mujoco>""")
    sensors.check(model, sensors.contact("paired"), "env.rewards.a")  # through its pair
    sensors.check(model, sensors.contact("colliding"), "env.rewards.b")
    sensors.check(model, sensors.self_contacts("paired", 1), "env.rewards.c")  # its subtree's
    with pytest.raises(LabError) as err:
        sensors.check(model, sensors.contact("child"), "env.terminations.child_contact")
    assert err.value.message == (
        "env.terminations.child_contact reads the contacts of body 'child', but none of its "
        "geoms touches anything (contype and conaffinity 0, in no contact pair)")
    assert "env.robot.collisions" in err.value.hint
