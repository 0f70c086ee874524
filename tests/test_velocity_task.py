"""Velocity commands, the contact terms built on them, and the go1-flat task: terms against
hand-computed cases on the real Go1 model at small sizes."""

from __future__ import annotations

import copy
import importlib.util
import json
import math

import mujoco
import pytest
import torch
from backends import lift_and_copy, worst_gaps
from conftest import needs_menagerie
from lab_locomotion import quadruped
from lab_locomotion.go1_datasheet import ROBOT as DATASHEET_GO1
from lab_locomotion.plugin import HERE
from oneline import assert_one_line_error
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.envs import metrics
from labcli.envs.env import EPISODE
from labcli.errors import LabError
from labcli.gym import make_env
from labcli.plugins import registry
from labcli.runs import config

GO1_XML = HERE / "go1.xml"  # go1-rough's
DT = 4 * 0.005  # go1-flat: 200 Hz physics, decimation 4
HAVE_WARP = all(importlib.util.find_spec(m) for m in ("warp", "mujoco_warp"))
pytestmark = needs_menagerie("unitree_go1")  # go1-flat's robot


def lab(*args: str, logs):
    return CliRunner().invoke(app, list(args), env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "300"})


def go1(n: int = 4, *overrides: str, **kwargs):
    env = make_env("go1-flat", num_envs=n, seed=0,
                   overrides=["env.observation_noise=false", *overrides], **kwargs)
    env.reset()
    return env


def terms(env) -> dict:
    t = env.task
    return {b.name: b for b in [*t._rewards, *t._terminations, *t._events,
                                *t._commands.values()]}


def yaw_quat(yaw: float) -> list[float]:
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


def test_go1_rough_s_mjcf_is_written_from_its_numbers_and_stands_on_its_feet():
    assert GO1_XML.read_text() == quadruped.mjcf(
        DATASHEET_GO1, quadruped.standing_height(DATASHEET_GO1), "go1_datasheet")
    model = mujoco.MjModel.from_xml_path(str(GO1_XML))
    assert (model.nu, model.nq) == (12, 19)
    # Unitree's published masses: 5.204 kg trunk, 4 legs of 0.68 + 1.009 + 0.196 kg.
    assert model.body_subtreemass[1] == pytest.approx(5.204 + 4 * (0.68 + 1.009 + 0.196))
    assert model.actuator_forcerange[:, 1].tolist() == [23.7, 23.7, 35.55] * 4
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    for _ in range(400):  # 2 s holding the standing pose
        mujoco.mj_step(model, data)
    feet = [model.body(f"{leg}_foot").id for leg in quadruped.LEGS]
    touching = {int(model.geom_bodyid[c.geom[i]]) for c in data.contact[:data.ncon]
                for i in (0, 1)}
    assert set(feet) <= touching and len(touching - set(feet)) == 1  # the feet and the floor
    assert 0.25 < data.qpos[2] < 0.33 and data.qpos[3] > 0.999  # upright, trunk off the floor


def test_commands_are_drawn_from_their_ranges_standing_envs_get_zero():
    env = go1(512, "env.commands.base_velocity.rel_standing_envs=0.25",
              "env.commands.base_velocity.heading_command=false")
    command = env.task.command("base_velocity")
    values = command.command
    standing = command.standing_env
    assert 0.15 < standing.float().mean() < 0.35
    assert (values[standing] == 0).all()
    moving = values[~standing]
    assert (moving.abs() <= 1.0).all() and moving.abs().max() > 0.9
    # Observed as is; on two threads or more `env.task` is env shard 0's, its envs first.
    assert env.observations()[:len(values), 9:12].tolist() == values.float().tolist()
    env.close()


def test_heading_control_steers_the_yaw_rate_toward_the_heading_within_the_range():
    env = go1(4, "env.commands.base_velocity.rel_standing_envs=0.0")
    command = env.task.command("base_velocity")
    r = env.task.robot
    r.root_quat[:] = torch.tensor(yaw_quat(0.3), dtype=torch.float64)
    command.heading[:] = torch.tensor([0.5, -1.0, -2.5, -2.9], dtype=torch.float64)
    r.update()  # as after a step: the robot's yaw is the new state's
    command._steer(r.yaw)
    # 0.5 x the heading error, clipped to the yaw-rate range (-1, 1). The last error, -3.2 rad,
    # is +3.08 the short way round: it turns left.
    assert command.command[:, 2].tolist() == pytest.approx([0.1, -0.65, -1.0, 1.0], abs=1e-9)
    env.close()


def test_commands_are_drawn_again_when_their_time_runs_out():
    env = go1(64, "env.commands.base_velocity.resampling_time_range=[0.05,0.05]",
              "env.commands.base_velocity.heading_command=false")
    command = env.task.command("base_velocity")
    before = command.command.clone()
    env.step(torch.zeros(64, 12))  # 0.02 s left of 0.05
    env.step(torch.zeros(64, 12))
    assert torch.equal(command.command, before)
    env.step(torch.zeros(64, 12))  # 0.05 s: drawn again
    assert (command.command != before).any(dim=1).float().mean() > 0.9
    env.close()


def test_on_the_cpu_only_the_blocks_whose_command_or_push_is_due_draw():
    """As resets do, command resampling and pushes draw only for the blocks of envs (here one
    env each) whose time is up: what a block draws does not depend on its neighbours' timers,
    in one process or in shards, and a step where none is due draws nothing."""
    env = go1(8)  # no observation noise; commands and pushes 10 s or more away
    command, push = env.task.command("base_velocity"), terms(env)["push_robot"].made

    def blocks_drawn_in_a_step() -> list[int]:
        before = env.get_state()["generator"]
        env.step(torch.zeros(8, 12))
        after = env.get_state()["generator"]
        return [b for b in range(8) if not torch.equal(before[b], after[b])]

    assert blocks_drawn_in_a_step() == []
    command.time_left[3] = 0.0
    assert blocks_drawn_in_a_step() == [3]
    assert command.time_left[3] > 0.0  # drawn anew
    push.time_left[5] = 0.0
    assert blocks_drawn_in_a_step() == [5]
    assert blocks_drawn_in_a_step() == []
    env.close()


def test_tracking_rewards_are_exp_kernels_of_the_error_in_the_base_frame():
    env = go1(4)
    t, r = terms(env), env.task.robot
    command = env.task.command("base_velocity")
    command.command[:] = torch.tensor([1.0, 0.0, 0.5], dtype=torch.float64)
    r.root_quat[:] = torch.tensor(yaw_quat(math.pi / 2), dtype=torch.float64)
    r.root_lin_vel_w[:] = torch.tensor([0.0, 0.8, 0.0], dtype=torch.float64)  # 0.8 forward
    r.root_ang_vel_b[:] = torch.tensor([0.0, 0.0, 0.2], dtype=torch.float64)
    env.task.update()
    assert t["track_lin_vel_xy_exp"].compute()[0].item() == pytest.approx(
        math.exp(-0.2**2 / 0.25))
    assert t["track_ang_vel_z_exp"].compute()[0].item() == pytest.approx(
        math.exp(-0.3**2 / 0.25))
    env.close()


def _set_feet(env, forces_z: list[float]) -> None:
    """Write the feet's contact sensors (FL, FR, RL, RR) as if the physics had: z forces (N)."""
    foot = terms(env)["feet_air_time"].made.contacts
    for i, body in enumerate(foot.bodies):
        sid = mujoco.mj_name2id(env.sim.model, mujoco.mjtObj.mjOBJ_SENSOR, f"lab:contact:{body}")
        adr = int(env.sim.model.sensor_adr[sid])
        env.sim.sensordata[:, adr:adr + 3] = torch.tensor([0.0, 0.0, forces_z[i]],
                                                          dtype=env.sim.sensordata.dtype)
    env.task.update()


def test_feet_air_time_rewards_each_touchdown_by_its_time_in_the_air():
    env = go1(2)
    air_time = terms(env)["feet_air_time"]
    command = env.task.command("base_velocity")
    command.command[:] = torch.tensor([[1.0, 0.0, 0.0], [0.05, 0.0, 0.0]], dtype=torch.float64)
    _set_feet(env, [30.0, 30.0, 30.0, 30.0])
    air_time.compute(), air_time.after_step()
    for _ in range(30):  # FL in the air for 30 steps (0.6 s), the others standing
        _set_feet(env, [0.0, 30.0, 30.0, 30.0])
        assert air_time.compute().tolist() == [0.0, 0.0]
        air_time.after_step()
    _set_feet(env, [30.0, 30.0, 30.0, 30.0])  # touchdown in the 31st step
    reward = air_time.compute()
    # 31 steps in the air minus the 0.5 s threshold; none under 0.1 m/s of command.
    assert reward.tolist() == pytest.approx([31 * DT - 0.5, 0.0])
    air_time.after_step()
    assert air_time.compute().tolist() == [0.0, 0.0]  # standing: no new touchdown
    env.close()


def test_undesired_contacts_count_the_bodies_touching(tmp_path):
    env = go1(2, "env.rewards.undesired_contacts={weight: -1.0, bodies: ['.*_thigh']}")
    undesired = terms(env)["undesired_contacts"]
    assert undesired.compute().tolist() == [0.0, 0.0]
    thighs = undesired.made.contacts
    for body in thighs.bodies[:3]:
        sid = mujoco.mj_name2id(env.sim.model, mujoco.mjtObj.mjOBJ_SENSOR, f"lab:contact:{body}")
        adr = int(env.sim.model.sensor_adr[sid])
        env.sim.sensordata[0, adr + 2] = 5.0  # over the 1 N threshold
    env.task.update()
    assert undesired.compute().tolist() == [3.0, 0.0]
    env.close()


def test_resets_scale_the_joints_shift_the_com_and_add_base_mass():
    env = go1(64)
    r = env.task.robot
    # Menagerie's standing pose has the hips at 0: scaled, they stay there.
    scaled = r.default_joint_pos[0] != 0
    assert scaled.sum() == 8 and (r.joint_pos[:, ~scaled] == 0).all()
    ratio = r.joint_pos[:, scaled] / r.default_joint_pos[:, scaled]
    inside = ((r.joint_pos - r.joint_lower).abs().gt(1e-9)
              & (r.joint_pos - r.joint_upper).abs().gt(1e-9))[:, scaled]
    # Drawn in (0.5, 1.5) x the default, or clamped at a limit.
    assert ((ratio >= 0.5 - 1e-9) & (ratio <= 1.5 + 1e-9) | ~inside).all()
    assert ratio.std() > 0.1
    model = env.sim.model  # the nominal model, which the envs' copies vary
    com = env.sim.model_field("body_ipos")[:, 1] - torch.as_tensor(model.body_ipos[1])
    assert (com[:, :2].abs() <= 0.05).all() and (com[:, 2].abs() <= 0.01).all()
    assert com[:, 0].std() > 0.01
    mass = env.sim.model_field("body_mass")[:, 1] - model.body_mass[1]
    assert ((mass >= -1.0) & (mass <= 3.0)).all() and mass.std() > 0.5
    yaw = torch.atan2(r.rotation[:, 1, 0], r.rotation[:, 0, 0])
    assert yaw.abs().max() > 2.5  # reset_base turns the robot about z
    env.close()


def test_success_and_tracking_errors_per_episode_are_logged():
    """Standing still under a command to stand: errors ~0, every timed-out episode succeeds;
    the same under a command of 1 m/s: a mean xy error of ~1 m/s, none succeeds."""
    for speed, succeeded in ((0.0, 1.0), (1.0, 0.0)):
        env = go1(8, "env.episode_length_s=0.5", "env.events.reset_base=null",
                  "env.events.reset_robot_joints=null", "env.events.push_robot=null",
                  "env.commands.base_velocity.heading_command=false",
                  f"env.commands.base_velocity.lin_vel_x=[{speed},{speed}]",
                  "env.commands.base_velocity.lin_vel_y=[0,0]",
                  "env.commands.base_velocity.ang_vel_z=[0,0]",
                  "env.commands.base_velocity.rel_standing_envs=0")
        hold = torch.zeros(8, 12)
        for _ in range(25):
            env.step(hold)
        stats = env.pop_stats()
        env.close()
        assert stats[metrics.EPISODES] == 8
        assert stats[metrics.SUCCESS_RATE] == succeeded
        # Menagerie's Go1 settles from its keyframe's height in the first steps.
        assert stats["Metrics/base_velocity/error_vel_xy"] == pytest.approx(speed, abs=0.15)
        assert stats["Metrics/base_velocity/error_vel_yaw"] < 0.1


@pytest.mark.parametrize("success", [True, False])
def test_a_termination_named_a_success_ends_its_episodes_as_successes(success):
    """A goal reached ends the episode early, as a success (and terminal: not bootstrapped).
    Here the goal is the feet touching the ground (Menagerie's Go1 has its feet on the calves):
    it ends every episode within steps."""
    env = go1(8, "env.terminations.base_contact.bodies=[.*_calf]",
              f"env.terminations.base_contact.success={str(success).lower()}",
              "env.events.push_robot=null")
    ended = torch.zeros(8, dtype=torch.bool)
    for _ in range(10):
        _, _, terminated, truncated, info = env.step(torch.zeros(8, 12))
        done = info[f"_{EPISODE}"]
        assert torch.equal(terminated, done) and not truncated.any()
        assert torch.equal(info[EPISODE]["success"], done & success)
        ended |= done
    stats = env.pop_stats()
    env.close()
    assert ended.all() and stats[metrics.SUCCESS_RATE] == float(success)


def test_a_termination_is_a_time_out_or_a_success_not_both():
    with pytest.raises(LabError, match="a time-out or a success, not both"):
        go1(2, "env.terminations.base_contact.time_out=true",
            "env.terminations.base_contact.success=true")


def test_an_error_window_judges_the_velocity_kept_over_a_stride_not_each_step_s_sway():
    """A yaw rate that swings ±0.4 rad/s each step around the commanded 0 (a humanoid's pelvis
    turning with each step): 0.4 rad/s of mean error step by step, a fiftieth of it averaged
    over 0.2 s. A steady error of 0.5 m/s is 0.5 m/s either way: an episode starts with the
    command as its error, as from rest."""
    for window, yaw_error in ((0.0, 0.4), (0.2, 0.02)):
        env = go1(2, "env.commands.base_velocity.heading_command=false",
                  "env.commands.base_velocity.lin_vel_x=[0.5,0.5]",
                  "env.commands.base_velocity.lin_vel_y=[0,0]",
                  "env.commands.base_velocity.ang_vel_z=[0,0]",
                  "env.commands.base_velocity.rel_standing_envs=0",
                  f"env.commands.base_velocity.error_window={window}")
        command, r = env.task.command("base_velocity"), env.task.robot
        command.reset(torch.ones(2, dtype=torch.bool))
        r.root_quat[:] = torch.tensor(yaw_quat(0.0), dtype=torch.float64)
        r.root_lin_vel_w[:] = 0.0
        for k in range(100):
            r.root_ang_vel_b[:] = torch.tensor([0.0, 0.0, 0.4 * (-1) ** k], dtype=torch.float64)
            env.task.update()
            command.after_step()
        lin, yaw = command.mean_errors[0].tolist()
        env.close()
        assert lin == pytest.approx(0.5)
        assert yaw == pytest.approx(yaw_error, abs=0.01)


@pytest.mark.parametrize("how", ["resume", "deepcopy"])
def test_a_resumed_or_copied_go1_flat_steps_on_exactly_as_the_original(how):
    """What the task carries from step to step goes with the env's state: the commands and
    their timers and errors, the pushes' timers, the feet's air time, each env's friction, mass
    and center of mass. Commands and pushes come often here, so the next steps use all of it.
    (A resumed env's first observations draw their noise anew: noise stays off there.)"""
    sets = (f"env.observation_noise={how == 'deepcopy'}",
            "env.commands.base_velocity.resampling_time_range=[0.2,0.4]",
            "env.events.push_robot.interval_s=[0.1,0.3]")
    env = go1(8, *sets)
    gen = torch.Generator().manual_seed(0)
    for _ in range(15):
        env.step(torch.rand(8, 12, generator=gen) * 2 - 1)
    if how == "deepcopy":
        twin = copy.deepcopy(env)
    else:
        twin = make_env("go1-flat", num_envs=8, seed=5, overrides=list(sets))
        twin.resume_from(env.get_state())
        twin.reset()
    try:
        for field in ("body_mass", "body_ipos"):
            assert torch.equal(twin.sim.model_field(field), env.sim.model_field(field))
        for _ in range(40):
            action = torch.rand(8, 12, generator=gen) * 2 - 1
            got, want = twin.step(action), env.step(action)
            for g, w in zip(got[:4], want[:4], strict=True):
                assert torch.equal(g, w)
        assert twin.pop_stats() == env.pop_stats()
    finally:
        twin.close()
        env.close()


@pytest.mark.gpu
@pytest.mark.skipif(not (HAVE_WARP and torch.cuda.is_available()),
                    reason='needs a CUDA GPU and MuJoCo Warp (pip install -e ".[warp]")')
def test_a_resumed_go1_flat_on_the_gpu_carries_its_task_state():
    """On the warp backend too, where the per-env model fields are MuJoCo Warp's batched arrays
    and the step replays as a CUDA graph: the task's state comes back in place, and the next
    step's observations follow. (What a GPU draws after a resume differs: docs/robustness.md.)"""
    sets = ["env.observation_noise=false",
            "env.commands.base_velocity.resampling_time_range=[0.2,0.4]",
            "env.events.push_robot.interval_s=[0.1,0.3]"]
    made = [make_env("go1-flat", num_envs=64, backend="warp", device="cuda", seed=seed,
                     overrides=sets) for seed in (0, 5)]
    env, twin = made
    try:
        env.reset()
        gen = torch.Generator(device="cuda").manual_seed(0)
        for _ in range(15):
            env.step(torch.rand(64, 12, generator=gen, device="cuda") * 2 - 1)
        twin.resume_from(env.get_state())
        twin.reset()
        theirs = twin.task.state()
        for name, value in env.task.state().items():
            assert torch.equal(theirs[name], value), name
        action = torch.rand(64, 12, generator=gen, device="cuda") * 2 - 1
        got, want = twin.step(action), env.step(action)
        assert torch.allclose(got[0], want[0], atol=1e-4)
    finally:
        twin.close()
        env.close()


def test_weights_are_per_second_as_isaac_lab_s():
    env = go1(2)
    assert env._weights[0].tolist() == pytest.approx(
        [w * DT for w in env.cfg.weights(1.0).values()])
    env.close()


def test_sb3_s_gpu_defaults_take_the_rate_measured_there_and_the_cpu_s_stay():
    spec, sb3 = registry.get_task("go1-flat"), registry.get_framework("sb3")
    _, gpu = config.resolve(spec, sb3, gpu_scale=True)
    env, cpu = config.resolve(spec, sb3)
    assert gpu.learning_rate == 1e-3 and gpu.batch_size == 4096 * 24 // 4
    assert cpu.learning_rate == 5e-4 and cpu.batch_size == env.num_envs * 24 // 4


def test_the_cpu_steps_playground_s_contacts_and_the_gpu_the_model_s_own():
    """go1-flat's CPU defaults: pyramidal cones and feet of 3 contact dimensions on 1,024 envs,
    a runaway past 100 rad/s or m/s ended as diverged, and twice the entropy bonus; on the GPU
    Menagerie's elliptic cones and feet of 6, which the built model shows, lab's own limit and
    Isaac Lab's bonus."""
    spec, rsl_rl = registry.get_task("go1-flat"), registry.get_framework("rsl_rl")
    cpu, cpu_agent = config.resolve(spec, rsl_rl)
    gpu, gpu_agent = config.resolve(spec, rsl_rl, gpu_scale=True)
    assert (cpu.num_envs, cpu_agent.max_iterations) == (1024, 1000)
    assert (gpu.num_envs, gpu_agent.max_iterations) == (4096, 300)
    assert (cpu.unstable_velocity, gpu.unstable_velocity) == (100.0, 1e6)
    assert (cpu_agent.entropy_coef, gpu_agent.entropy_coef) == (0.02, 0.01)
    built = {scale: spec.task_class.build_model(cfg, spec.model)
             for scale, cfg in (("cpu", cpu), ("gpu", gpu))}
    assert built["cpu"].opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL
    assert built["gpu"].opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    for scale, condim in (("cpu", 3), ("gpu", 6)):
        model = built[scale]
        feet = [g for g in range(model.ngeom) if model.geom_priority[g] == 1]
        assert len(feet) == 4 and set(model.geom_condim[feet]) == {condim}, scale


def test_train_play_and_export_go1_from_the_command_line(tmp_path):
    logs = tmp_path / "logs"
    trained = lab("train", "--task", "go1-flat", "--framework", "rsl_rl", "--num-envs", "8",
                  "--max-iterations", "2", "--set", "agent.num_steps_per_env=8", logs=logs)
    assert trained.exit_code == 0, trained.output
    played = lab("play", "--last", "--task", "go1-flat", "--episodes", "1", logs=logs)
    assert played.exit_code == 0 and "1 episodes" in played.stdout, played.output
    exported = lab("export", "onnx", "--last", "--task", "go1-flat", logs=logs)
    assert exported.exit_code == 0, exported.output
    from labcli.runs.play import load

    run = next(logs.glob("rsl_rl/go1-flat/*"))
    loaded = load(run_dir=run)
    assert loaded.env.cfg.events.push_robot is None and not loaded.env.cfg.observation_noise
    # Trained unclipped (±100, as Isaac Lab), played and exported unclipped.
    assert loaded.policy.clip == loaded.env.clip_actions == 100.0
    meta = json.loads((run / "exported" / "policy.onnx.json").read_text())
    assert meta["output"]["range"] == [-100.0, 100.0]
    loaded.env.close()


DC_MOTORS = ["env.robot.actuators.hip.model=dc_motor", "env.robot.actuators.knee.model=dc_motor"]


@pytest.mark.gpu
@pytest.mark.skipif(not (HAVE_WARP and torch.cuda.is_available()),
                    reason='needs a CUDA GPU and MuJoCo Warp (pip install -e ".[warp]")')
@pytest.mark.parametrize("extra", [[], ["env.actions.delay=[5,5]"], DC_MOTORS,
                                   [*DC_MOTORS, "env.actions.delay=[5,5]"], "mlp"],
                         ids=["held", "delayed", "dc_motor", "dc_motor-delayed", "mlp"])
def test_both_backends_agree_on_a_short_go1_rollout(extra, tmp_path):
    """As test_robot_tasks' check for ant and humanoid: from the same state, lifted off the
    floor, the same actions give the same observations and rewards on both backends; also
    with each physics step's own control (a motor's latency, motor models' torques computed
    between the physics steps, inside the step's CUDA graph)."""
    if extra == "mlp":
        from test_motors import pd_net

        extra = pd_net(tmp_path / "net.pt")
    overrides = ["env.observation_noise=false", "env.events.push_robot=null", *extra]
    cpu = make_env("go1-flat", num_envs=8, backend="cpu", device="cpu", seed=0,
                   overrides=overrides)
    gpu = make_env("go1-flat", num_envs=8, backend="warp", device="cuda", seed=0,
                   overrides=overrides)
    cpu.reset(), gpu.reset()
    lift_and_copy(cpu, gpu)
    # What each backend drew at reset differs: the per-env model fields (mass, center of
    # mass) and the commands. The same on both.
    for field in ("body_mass", "body_ipos"):
        gpu.sim.model_field(field).copy_(cpu.sim.model_field(field))
        gpu.sim.model_changed(field, torch.ones(8, dtype=torch.bool, device="cuda"))
    mine, theirs = cpu.task.command("base_velocity"), gpu.task.command("base_velocity")
    for name in ("command", "heading", "time_left", "heading_env", "standing_env"):
        getattr(theirs, name).copy_(getattr(mine, name))
    worst_obs, worst_reward = worst_gaps(cpu, gpu)
    cpu.close(), gpu.close()
    assert worst_obs < 0.05 and worst_reward < 0.05, (worst_obs, worst_reward)


def test_a_collision_set_that_leaves_the_trunk_out_is_refused_before_training(tmp_path):
    """Naming only the feet in env.robot.collisions turns the trunk's collisions off, and
    go1-flat's base-contact termination with them: one line, before anything is written."""
    result = lab("train", "--task", "go1-flat", "--framework", "rsl_rl", "--num-envs", "2",
                 "--max-iterations", "1", "--set",
                 'env.robot.collisions=[{"bodies": [".*_calf"], "types": ["sphere"]}]',
                 logs=tmp_path / "logs")
    assert_one_line_error(result, "env.terminations.base_contact", "body 'trunk'",
                          "env.robot.collisions")
    assert not (tmp_path / "logs").exists() or not any((tmp_path / "logs").rglob("*.json"))
    # Every other geom kept as the model has it: it trains.
    result = lab("train", "--task", "go1-flat", "--framework", "rsl_rl", "--num-envs", "2",
                 "--max-iterations", "1", "--set", 'env.robot.collisions=[{"bodies": '
                 '[".*_calf"], "types": ["sphere"], "condim": 3}, {"bodies": [".*"]}]',
                 logs=tmp_path / "logs")
    assert result.exit_code == 0, result.output
