"""Motor models lab computes at every physics step (`env.robot.actuators.<group>.model`):
ideal PD, DC motor and a learned actuator net against hand-computed torques, the physics of
an ideal PD against MuJoCo's own servo, with a latency, in env shards, through resume, the
export's description and the plain-MuJoCo loop's law."""

from __future__ import annotations

import json
import warnings

import mujoco
import numpy as np
import pytest
import torch
from conftest import needs_menagerie, needs_warp
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.envs.make import make_env as build
from labcli.envs.shards import ShardedVecEnv
from labcli.gym import make_env
from labcli.plugins import registry
from labcli.runs import config as configs
from labcli.sim2sim import _Motors

BASE = ["env.observation_noise=false", "env.events.push_robot=null"]
HIP, KNEE = "env.robot.actuators.hip", "env.robot.actuators.knee"
pytestmark = needs_menagerie("unitree_go1")  # go1-flat's robot


def go1(n: int, *overrides: str):
    # The cpu backend also where CUDA is (the warp one: test_velocity_task's backends check).
    env = make_env("go1-flat", num_envs=n, seed=0, overrides=[*BASE, *overrides],
                   backend="cpu", device="cpu")
    env.reset()
    return env


def both(model: str) -> list[str]:
    return [f"{HIP}.model={model}", f"{KNEE}.model={model}"]


def actions(steps: int, n: int, seed: int = 0) -> list[torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return [torch.rand(n, 12, generator=gen) * 0.6 - 0.3 for _ in range(steps)]


def test_an_ideal_pd_is_the_physics_of_mujocos_servo_of_the_same_gains():
    # Without damping, MuJoCo's position servo computes kp (target - q) from the state at the
    # start of each physics step too: the same trajectories, to rounding. One physics step an
    # env step: the cpu backend then cold-starts the solver at the same steps on both.
    same = ["env.decimation=1", f"{HIP}.damping=0", f"{KNEE}.damping=0"]
    servo, pd = go1(4, *same), go1(4, *same, *both("ideal_pd"))
    assert servo.task.substep is None and pd.task.substep is not None
    assert pd.sim.model.actuator_biastype[0] == mujoco.mjtBias.mjBIAS_NONE  # a plain motor
    for a in actions(40, 4):
        servo.step(a), pd.step(a)
    assert torch.allclose(servo.sim.qpos, pd.sim.qpos, atol=1e-9, rtol=0)
    servo.close(), pd.close()


def set_joints(env, q: list[float], qd: list[float], target: list[float]) -> None:
    """The hips' (actuators 0, 3, 6, 9) positions, velocities and targets."""
    task = env.task
    for i, (a, b, c) in enumerate(zip(q, qd, target, strict=True)):
        joint = task.robot.joint_ids[3 * i]
        task.sim.qpos[:, task.model.jnt_qposadr[joint]] = a
        task.sim.qvel[:, task.model.jnt_dofadr[joint]] = b
        task.targets[:, 3 * i] = c


def hip_torques(env) -> list[float]:
    env.task.substep(0)
    return [round(float(env.sim.ctrl[0, 3 * i]), 9) for i in range(4)]


def test_ideal_pd_torques_against_hand_computed_ones():
    env = go1(1, *both("ideal_pd"), f"{HIP}.stiffness=20", f"{HIP}.damping=0.5",
              f"{HIP}.effort_limit=10")
    # kp (target - q) - kd qd: 20 * 0.1 - 0.5 * 1 = 1.5; 20 * 1 - 0.5 = 19.5 -> 10; -20 * 1
    # + 0.5 * 1 ... each clipped to +-10.
    set_joints(env, q=[0.0, 0.0, 1.0, 0.2], qd=[1.0, 1.0, -1.0, 0.0],
               target=[0.1, 1.0, 0.0, 0.0])
    assert hip_torques(env) == [1.5, 10.0, -10.0, -4.0]
    env.close()


def test_a_dc_motor_gives_less_torque_with_its_speed_and_more_against_it():
    env = go1(1, *both("dc_motor"), f"{HIP}.stiffness=20", f"{HIP}.damping=0",
              f"{HIP}.effort_limit=10", f"{HIP}.saturation_effort=12",
              f"{HIP}.velocity_limit=10")
    # The line: at qd = 5, at most 12 (1 - 0.5) = 6 forward and down to max(-10, 12 (-1.5));
    # at qd = -5, up to min(10, 12 * 1.5) forward and -6 backward; past the velocity limit
    # (qd = 12) it cannot push forward at all.
    set_joints(env, q=[0.0, 0.0, 0.0, 0.0], qd=[5.0, 5.0, -5.0, 12.0],
               target=[1.0, -1.0, -1.0, 1.0])
    assert hip_torques(env) == [6.0, -10.0, -6.0, 0.0]
    env.close()


def linear_net(path, weights: list[float]) -> str:
    """A TorchScript actuator net whose torque is weights . input."""
    net = torch.nn.Linear(len(weights), 1, bias=False)
    with torch.no_grad():
        net.weight.copy_(torch.tensor([weights]))
    with warnings.catch_warnings():  # torch 2.13 deprecates TorchScript, which such nets are
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.jit.save(torch.jit.script(net), str(path))
    return str(path)


def mlp(path) -> list[str]:
    """The knees driven by a net over the position errors (x2) and velocities (x0.5) of the
    last three physics steps: torque = 3 (e . (1, 10, 100) + v . (0.1, 0.01, 0.001))."""
    file = linear_net(path, [1.0, 10.0, 100.0, 0.1, 0.01, 0.001])
    net = f"{KNEE}.network"
    return [f"{KNEE}.model=mlp", f"{net}.file={file}", f"{net}.input_idx=[0,1,2]",
            f"{net}.pos_scale=2", f"{net}.vel_scale=0.5", f"{net}.torque_scale=3",
            f"{KNEE}.effort_limit=1000"]


def pd_net(path) -> list[str]:
    """The knees driven by a net that is a PD law of the joint's own gains' size (kp 36, kd
    2.3), a tame one for comparing physics: torque = 36 e0 - 2.3 v0."""
    file = linear_net(path, [36.0, 0.0, -2.3, 0.0])
    return [f"{KNEE}.model=mlp", f"{KNEE}.network.file={file}",
            f"{KNEE}.network.input_idx=[0,1]"]


def test_a_learned_actuator_net_sees_its_joints_history(tmp_path):
    env = go1(2, *mlp(tmp_path / "net.pt"))
    task = env.task
    knee = task.robot.joint_ids[2]  # FR's calf: the first knee
    qadr, dadr = task.model.jnt_qposadr[knee], task.model.jnt_dofadr[knee]
    torques = []
    for error, velocity in ((0.1, 1.0), (0.2, 2.0), (0.3, 4.0)):
        task.sim.qpos[:, qadr] = -1.5
        task.sim.qvel[:, dadr] = velocity
        task.targets[:, 2] = -1.5 + error
        task.substep(0)
        torques.append(float(task.sim.ctrl[0, 2]))
    # Newest first: errors 2 (0.3, 0.2, 0.1), velocities 0.5 (4, 2, 1).
    want = 3 * (2 * (0.3 + 10 * 0.2 + 100 * 0.1) + 0.5 * (0.1 * 4 + 0.01 * 2 + 0.001 * 1))
    assert torques[2] == pytest.approx(want, rel=1e-6)
    # The first call saw no past: zeros stand for it.
    assert torques[0] == pytest.approx(3 * (2 * 0.1 + 0.5 * 0.1), rel=1e-6)
    # A reset forgets the env's history, and only its own.
    net_state = task.motors.nets["knee"]
    task.reset(torch.tensor([True, False]), task.rng)
    assert not net_state.errors[0].any() and net_state.errors[1].any()
    env.close()


def test_a_resumed_env_keeps_the_nets_history(tmp_path):
    extra = mlp(tmp_path / "net.pt")
    env = go1(4, *extra)
    for a in actions(5, 4):
        env.step(a)
    twin = make_env("go1-flat", num_envs=4, seed=7, overrides=[*BASE, *extra], backend="cpu",
                    device="cpu")
    twin.resume_from(env.get_state())
    twin.reset()
    for a in actions(5, 4, seed=1):
        env.step(a), twin.step(a)
        assert torch.equal(twin.sim.qpos, env.sim.qpos)
    env.close(), twin.close()


def test_a_latency_delays_the_targets_the_motor_pulls_toward():
    # As test_actuator_delay's: a lag of one env step is the physics of each action sent one
    # step later, also when lab computes the torques.
    late = go1(4, *both("dc_motor"), "env.actions.delay=[4,4]")
    now = go1(4, *both("dc_motor"), "env.actions.delay=[0,0]")
    sent = actions(15, 4)
    for t, a in enumerate(sent):
        late.step(a), now.step(sent[max(t - 1, 0)])
        assert torch.equal(late.sim.qpos, now.sim.qpos), t
    late.close(), now.close()


def test_env_shards_step_the_motors_as_one_process_does():
    spec = registry.get_task("go1-flat")
    settings = configs.parse_set([*BASE, *both("dc_motor")])["env"]
    cfg = configs.build(spec.config_class, "env", [settings, {"num_envs": 128, "threads": 1}])
    sharded = ShardedVecEnv(spec, cfg, seed=0, shards=2)
    one = build(spec, cfg, backend="cpu", seed=0)
    assert type(one).__name__ == "LabVecEnv"
    sharded.reset(), one.reset()
    for a in actions(6, 128):
        o_sharded, *_ = sharded.step(a)
        o_one, *_ = one.step(a)
        assert torch.equal(o_sharded, o_one)
    sharded.close(), one.close()


def test_the_export_describes_each_motor_and_the_plain_loop_computes_its_torque(tmp_path):
    env = go1(1, f"{HIP}.model=dc_motor", f"{HIP}.velocity_limit=30.1")
    joints = env.task.deployment()["joints"]
    hip, knee = joints[0], joints[2]
    assert hip["motor"]["model"] == "dc_motor" and "motor" not in knee
    assert hip["command"] == "position target" and hip["stiffness"] > 0
    assert hip["motor"]["velocity_limit"] == 30.1
    assert env.task.action_commands()[0]["command"].endswith("dc_motor motor's torque toward it")
    # The plain loop's law gives lab's torques from the same state and targets.
    a = actions(3, 1)
    for step in a:
        env.step(step)
    loop = _Motors(env.sim.model, joints)
    data = mujoco.MjData(env.sim.model)
    data.qpos[:], data.qvel[:] = env.sim.qpos[0].numpy(), env.sim.qvel[0].numpy()
    target = env.task.targets[0].numpy().copy()
    env.task.substep(0)
    assert np.allclose(loop(target, data), env.sim.ctrl[0].numpy(), atol=1e-12)
    env.close()


def test_the_plain_loop_refuses_a_learned_actuator_net_in_one_line():
    with pytest.raises(ValueError, match="learned actuator net"):
        _Motors(mujoco.MjModel.from_xml_string("<mujoco/>"),
                [{"joint": "j", "motor": {"model": "mlp"}}])


@pytest.mark.parametrize("setting, says", [
    (f"{KNEE}.model=mlp", "an mlp actuator needs network"),
    (f"{KNEE}.model=dc_motor --set {KNEE}.velocity_limit=null", "a dc_motor needs velocity"),
    (f"{KNEE}.model=servo", "implicit"),
])
def test_an_incomplete_motor_model_is_one_line(setting, says):
    args = ["config", "show", "--task", "go1-flat", "--framework", "rsl_rl"]
    for part in setting.split(" --set "):
        args += ["--set", part]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    assert says in result.output and "Traceback" not in result.output


def test_an_actuator_net_that_is_not_torchscript_is_one_line(tmp_path):
    bad = tmp_path / "net.pt"
    bad.write_text("not a network")
    result = CliRunner().invoke(app, [
        "train", "--task", "go1-flat", "--framework", "rsl_rl", "--num-envs", "2",
        "--logs-dir", str(tmp_path / "logs"), "--set", f"{KNEE}.model=mlp",
        "--set", f"{KNEE}.network.file={bad}"])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert any("could not be loaded as TorchScript" in line for line in lines), result.output
    assert "Traceback" not in result.output


def test_exported_metadata_names_the_motor(tmp_path):
    result = CliRunner().invoke(app, [
        "train", "--task", "go1-flat", "--framework", "rsl_rl", "--num-envs", "4",
        "--logs-dir", str(tmp_path), "--set", "agent.max_iterations=1",
        "--set", f"{HIP}.model=ideal_pd"])
    assert result.exit_code == 0, result.output
    result = CliRunner().invoke(app, ["export", "onnx", "--last", "--logs-dir", str(tmp_path)])
    assert result.exit_code == 0, result.output
    meta = json.loads(next(tmp_path.rglob("policy.onnx.json")).read_text())
    joints = meta["deployment"]["joints"]
    assert joints[0]["motor"]["model"] == "ideal_pd" and "motor" not in joints[2]


GAINS = ["env.events.actuator_gains.stiffness_range=[0.5,1.5]",
         "env.events.actuator_gains.damping_range=[0.8,1.2]"]


def test_randomized_gains_reach_the_motors_each_env_its_own():
    # Hips as DC motors, knees as MuJoCo's servos: one event draws both, per env.
    env = go1(8, f"{HIP}.model=dc_motor", *GAINS)
    motors, nominal = env.task.motors, env.task.motors.gains
    kp0 = torch.tensor([kp for kp, _ in nominal], dtype=torch.float64)
    kd0 = torch.tensor([kd for _, kd in nominal], dtype=torch.float64)
    ratio_kp, ratio_kd = motors.kp / kp0, motors.kd / kd0
    assert ((ratio_kp >= 0.5) & (ratio_kp <= 1.5)).all()
    assert ((ratio_kd >= 0.8 - 1e-12) & (ratio_kd <= 1.2 + 1e-12)).all()
    assert len({tuple(row.tolist()) for row in motors.kp}) == 8
    # The knees' servos are drawn in their models, as before.
    knee_kp = [m.actuator_gainprm[2, 0] for m in env.sim.models]
    assert len(set(knee_kp)) == 8
    # The torque law uses each env's own gains.
    set_joints(env, q=[0.0] * 4, qd=[0.0] * 4, target=[0.01] * 4)
    env.task.substep(0)
    assert torch.allclose(env.sim.ctrl[:, 0], motors.kp[:, 0] * 0.01)
    # The export states the nominal gains.
    assert env.task.deployment()["joints"][0]["stiffness"] == pytest.approx(float(kp0[0]))
    # A resumed env has the gains it had.
    twin = make_env("go1-flat", num_envs=8, seed=9, backend="cpu", device="cpu",
                    overrides=[*BASE, f"{HIP}.model=dc_motor", *GAINS])
    twin.resume_from(env.get_state())
    twin.reset()
    assert torch.equal(twin.task.motors.kp, motors.kp)
    assert torch.equal(twin.task.motors.kd, motors.kd)
    env.close(), twin.close()


def test_a_nets_joints_are_exported_as_position_targets_without_gains(tmp_path):
    env = go1(1, *mlp(tmp_path / "net.pt"))
    knee = env.task.deployment()["joints"][2]
    assert knee["command"] == "position target"
    assert knee["stiffness"] is None and knee["motor"]["model"] == "mlp"
    assert knee["motor"]["network"]["input_idx"] == [0, 1, 2]
    env.close()


@pytest.mark.gpu
@needs_warp()
def test_each_world_of_mujoco_warp_pulls_with_its_own_motor_gains():
    env = make_env("go1-flat", num_envs=16, seed=0, backend="warp", device="cuda",
                   overrides=[*BASE, *both("dc_motor"), *GAINS])
    env.reset()
    motors = env.task.motors
    kp0 = torch.tensor([kp for kp, _ in motors.gains], device="cuda")
    ratio = motors.kp / kp0
    assert ((ratio >= 0.5 - 1e-5) & (ratio <= 1.5 + 1e-5)).all()
    assert len(motors.kp.unique(dim=0)) == 16
    for _ in range(10):  # the graphed step, replayed with each env's gains
        env.step(torch.zeros(16, 12, device="cuda"))
    assert torch.isfinite(env.sim.qpos).all()
    env.close()


def test_a_nets_run_exports_with_its_file_given_again_and_sim2sim_refuses_it(tmp_path):
    logs, settings = tmp_path / "logs", mlp(tmp_path / "net.pt")
    result = CliRunner().invoke(app, [
        "train", "--task", "go1-flat", "--framework", "rsl_rl", "--num-envs", "2",
        "--logs-dir", str(logs), "--set", "agent.max_iterations=1",
        *[a for s in settings for a in ("--set", s)]])
    assert result.exit_code == 0, result.output
    # A run dir is data: the file its params name is opened only when the user names it.
    export = ["export", "onnx", "--last", "--logs-dir", str(logs)]
    result = CliRunner().invoke(app, export)
    assert result.exit_code == 2 and "lab opens no file that a run dir names" in result.output
    file = next(s for s in settings if ".network.file=" in s)
    result = CliRunner().invoke(app, [*export, "--set", file])
    assert result.exit_code == 0, result.output
    result = CliRunner().invoke(app, ["sim2sim", "--last", "--logs-dir", str(logs),
                                      "--episodes", "1"])
    assert result.exit_code == 2, result.output
    assert "learned actuator net" in result.output and "Traceback" not in result.output


def test_a_net_named_by_a_bare_name_is_still_a_file_a_run_dir_names(tmp_path, monkeypatch):
    """A net's file resolves against the working directory: a run dir naming `net.pt` would
    load whatever `net.pt` is there, so lab asks for it as for a path."""
    monkeypatch.chdir(tmp_path)
    settings = [s.replace(str(tmp_path / "net.pt"), "net.pt") for s in mlp(tmp_path / "net.pt")]
    logs = tmp_path / "logs"
    result = CliRunner().invoke(app, [
        "train", "--task", "go1-flat", "--framework", "rsl_rl", "--num-envs", "2",
        "--logs-dir", str(logs), "--set", "agent.max_iterations=1",
        *[a for s in settings for a in ("--set", s)]])
    assert result.exit_code == 0, result.output
    play = ["play", "--last", "--logs-dir", str(logs), "--episodes", "1"]
    result = CliRunner().invoke(app, play)
    assert result.exit_code == 2 and "lab opens no file that a run dir names" in result.output
    assert "network.file=net.pt" in result.output
    result = CliRunner().invoke(app, [*play, "--set", f"{KNEE}.network.file=net.pt"])
    assert result.exit_code == 0, result.output
