"""The critic's own terms (`env.critic_observations: privileged`, `env.critic_extras`): mjlab's
G1 critic reads each foot's height, air time, contact and contact force after the policy's
terms; checked against the falling and standing robot, mirrored foot for foot."""

import io

import mujoco
import numpy as np
import pytest
import torch
from conftest import needs_menagerie, needs_warp
from lab_rsl_rl import framework as rsl_rl_framework
from oneline import assert_one_line_error
from rich.console import Console
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.envs.mdp.symmetry import mirror_of
from labcli.errors import LabError
from labcli.gym import make_env
from labcli.runs import training

pytestmark = needs_menagerie("unitree_g1")
PRIVILEGED = "env.critic_observations=privileged"
FEET = ("left_ankle_roll_link", "right_ankle_roll_link")
SOLES = ("left_foot", "right_foot")
# Dropped from 0.3 m above its standing height, without pushes: ~0.25 s in the air.
DROPPED = ["env.events.push_robot=null", "env.events.reset_base.pose_range.z=[0.3,0.3]"]


def g1(*overrides: str, num_envs: int = 2):
    return make_env("g1-flat", num_envs=num_envs, seed=0, backend="cpu", device="cpu",
                    overrides=[PRIVILEGED, *overrides])


def extras(env, info) -> dict[str, torch.Tensor]:
    """The critic's own columns by name, per env."""
    names = [n for group in env.task._critic_extra_names for n in group]
    values = info["critic_obs"][:, len(env.observation_names):]
    assert values.shape[1] == len(names)
    return dict(zip(names, values.T, strict=True))


def site_heights(env) -> np.ndarray:
    """The soles' heights in MuJoCo's own kinematics of env 0's state, `[feet]`."""
    model = env.task.model
    data = mujoco.MjData(model)
    data.qpos[:] = env.task.robot.sim.qpos[0].cpu().numpy()
    mujoco.mj_kinematics(model, data)
    return np.array([data.site(s).xpos[2] for s in SOLES])


def test_the_g1_s_feet_in_the_air_and_standing():
    env = g1(*DROPPED)
    try:
        assert env.critic_observation_size == len(env.observation_names) + 12
        zero = torch.zeros(2, env.single_action_space.shape[0])
        env.reset(seed=1)
        airborne, standing = [], []
        # Landed by step 15; at zero actions it stands until about step 45, then sinks.
        for step in range(40):
            *_, info = env.step(zero)
            (airborne if step < 8 else standing if step >= 25 else []).append(
                (extras(env, info), site_heights(env)))
        dt = env.task.step_dt
        for (before, _), (after, heights) in zip(airborne, airborne[1:], strict=False):
            for foot, sole_z in zip(FEET, heights, strict=True):
                assert after[f"foot_contact.{foot}"].tolist() == [0.0, 0.0]
                assert after[f"foot_air_time.{foot}"] - before[f"foot_air_time.{foot}"] == (
                    pytest.approx(dt, abs=1e-6))
                # The sensor holds the state at the last physics step's start: 5 ms earlier.
                assert float(after[f"foot_height.{foot}"][0]) == pytest.approx(sole_z, abs=0.01)
                assert float(after[f"foot_height.{foot}"][0]) > 0.1
                for axis in ("fx", "fy", "fz"):
                    assert after[f"foot_contact_forces.{foot}.{axis}"].tolist() == [0.0, 0.0]
        support = []
        for values, heights in standing:
            for foot, sole_z in zip(FEET, heights, strict=True):
                assert values[f"foot_contact.{foot}"].tolist() == [1.0, 1.0]
                assert values[f"foot_air_time.{foot}"].tolist() == [0.0, 0.0]
                assert abs(float(values[f"foot_height.{foot}"][0]) - sole_z) < 0.005
            # sign(f) log(1 + |f|) of each foot's vertical force, undone and summed
            fz = torch.stack([values[f"foot_contact_forces.{foot}.fz"] for foot in FEET])
            support.append((torch.expm1(fz.abs()) * torch.sign(fz)).sum(dim=0))
        # Standing still, the feet carry the robot's weight.
        weight = float(env.task.model.body_subtreemass[1]) * 9.81
        assert torch.stack(support).mean(dim=0).abs().tolist() == pytest.approx(
            [weight, weight], rel=0.05)
    finally:
        env.close()


def test_an_env_s_feet_read_the_same_whether_or_not_another_env_was_reset():
    """The observations of a step that reset some envs are the others' last ones: the air
    time an observation reads is the one the step kept, not counted on by the reset's
    recomputation (the compiled and GPU steps always take the reset path)."""
    env = g1(*DROPPED)  # at zero actions each G1 falls, one before the other
    try:
        zero = torch.zeros(2, env.single_action_space.shape[0])
        env.reset(seed=1)
        some_reset = 0
        for _ in range(120):
            *_, terminated, truncated, info = env.step(zero)
            done = terminated | truncated
            if done.any() and not done.all():
                some_reset += 1
                kept = ~done
                assert torch.equal(info["critic_obs"][kept], info["final_critic_obs"][kept])
                assert (extras(env, info)[f"foot_air_time.{FEET[0]}"][done] == 0.0).all()
        assert some_reset
    finally:
        env.close()


def test_the_critic_s_mirror_swaps_the_feet_and_refuses_world_frame_forces():
    env = g1()
    try:
        with pytest.raises(LabError, match="foot_contact_forces") as refused:
            mirror_of(env.task)
        assert "--set env.critic_extras.foot_contact_forces=null" in refused.value.hint
    finally:
        env.close()
    env = g1("env.critic_extras.foot_contact_forces=null")
    try:
        *_, info = env.reset(seed=0)
        for _ in range(3):
            *_, info = env.step(torch.randn(2, env.single_action_space.shape[0]))
        mirror = mirror_of(env.task)
        critic, policy_width = info["critic_obs"], len(env.observation_names)
        mirrored = mirror.critic_observations(critic)
        torch.testing.assert_close(mirrored[:, :policy_width],
                                   mirror.observations(critic[:, :policy_width]))
        for term in range(3):  # height, air time, contact: left and right swapped
            left, right = policy_width + 2 * term, policy_width + 2 * term + 1
            assert torch.equal(mirrored[:, left], critic[:, right])
            assert torch.equal(mirrored[:, right], critic[:, left])
        assert torch.equal(mirror.critic_observations(mirrored), critic)
    finally:
        env.close()


def test_rsl_rl_s_critic_reads_the_extras_and_mirrors_them(tmp_path, monkeypatch):
    seen = {}
    learn = rsl_rl_framework.LabRunner.learn

    def spied(runner, *args, **kwargs):
        seen["obs"] = runner.env.get_observations()
        return learn(runner, *args, **kwargs)

    monkeypatch.setattr(rsl_rl_framework.LabRunner, "learn", spied)
    outcome = training.train(
        "g1-flat", "rsl_rl", num_envs=4, max_iterations=2, logs_dir=tmp_path,
        overrides=[PRIVILEGED, "env.critic_extras.foot_contact_forces=null",
                   "agent.num_steps_per_env=8", "agent.actor_hidden_dims=[16]",
                   "agent.critic_hidden_dims=[16]", "agent.symmetry_augmentation=true"],
        console=Console(file=io.StringIO(), width=300))
    assert outcome.summary["iterations"] == 2
    assert seen["obs"]["critic"].shape[1] == seen["obs"]["policy"].shape[1] + 6
    saved = torch.load(outcome.run.dir / "model_2.pt", weights_only=True)
    critic_in = [v for k, v in saved["critic_state_dict"].items() if k.endswith("0.weight")]
    assert critic_in[0].shape[1] == seen["obs"]["critic"].shape[1]


def test_privileged_without_critic_extras_is_one_line(tmp_path):
    result = CliRunner().invoke(
        app, ["train", "--task", "go1-flat", "--framework", "rsl_rl", "--set", PRIVILEGED],
        env={"LAB_LOGS_DIR": str(tmp_path), "COLUMNS": "300"})
    assert_one_line_error(result, "critic_observations is privileged",
                          "env.critic_extras lists no term")


@pytest.mark.gpu
@needs_warp()
def test_the_replayed_gpu_step_reads_the_feet_as_the_cpu_does():
    """From the same state, 0.3 m up, the warp backend's replayed step gives the falling feet's
    heights, air times and contacts of the CPU's."""
    from backends import lift_and_copy

    quiet = [PRIVILEGED, "env.events.push_robot=null", "env.critic_extras.foot_contact_forces=null"]
    cpu = make_env("g1-flat", num_envs=2, seed=0, backend="cpu", device="cpu", overrides=quiet)
    gpu = make_env("g1-flat", num_envs=2, seed=0, backend="warp", device="cuda", overrides=quiet)
    try:
        cpu.reset(seed=1)
        gpu.reset(seed=1)
        lift_and_copy(cpu, gpu, height=0.3)
        zero = torch.zeros(2, cpu.single_action_space.shape[0])
        width = len(cpu.observation_names)
        for _ in range(8):  # the first steps capture the graph, the rest replay it
            *_, on_cpu = cpu.step(zero)
            *_, on_gpu = gpu.step(zero.cuda())
            torch.testing.assert_close(on_gpu["critic_obs"],
                                       gpu.task.critic_observations().float())
            torch.testing.assert_close(on_gpu["critic_obs"][:, width:].cpu(),
                                       on_cpu["critic_obs"][:, width:].float(), rtol=0, atol=2e-3)
    finally:
        cpu.close()
        gpu.close()
