"""A motor's latency (`env.actions.delay`, physics steps drawn per env and episode): which
control each physics step applies, against hand-computed cases and against the same physics
fed later actions; the draws; play and export."""

from __future__ import annotations

import json

import pytest
import torch
from conftest import needs_menagerie
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.gym import make_env

BASE = ["env.observation_noise=false", "env.events.push_robot=null"]
pytestmark = needs_menagerie("unitree_go1")  # go1-flat's robot


def go1(n: int, delay: str, *overrides: str):
    env = make_env("go1-flat", num_envs=n, seed=0,
                   overrides=[*BASE, f"env.actions.delay={delay}", *overrides])
    env.reset()
    return env


def test_each_physics_step_applies_the_newest_control_sent_lag_steps_before_it():
    # go1-flat: 4 physics steps an env step. A lag of 5: physics step k of env step t applies
    # the control sent ceil((5 - k) / 4) env steps before, c[t-2] at k = 0 and c[t-1] after.
    env = go1(2, "[5,5]")
    task = env.task
    sent = []
    for t in range(4):
        env.step(torch.full((2, 12), 0.1 * (t + 1)))
        sent.append(sent_now(task))
        if t == 0:  # the first control of an episode stands for those before it
            assert all(torch.equal(task.controls[k], sent[0]) for k in range(4))
    want = [sent[1], sent[2], sent[2], sent[2]]
    for k in range(4):
        assert torch.equal(task.controls[k], want[k]), k
    # The physics ends its step on the last control it applied.
    assert torch.equal(task.sim.ctrl, sent[2])
    env.close()


def sent_now(task) -> torch.Tensor:
    """The control the policy's last action asks for (before any latency)."""
    act = task.actuation
    return act.offset + act.scale * task.action


def test_a_lag_of_whole_env_steps_is_the_physics_of_actions_sent_that_much_later():
    # A lag of 4 physics steps is one env step: the same physics as an env without latency
    # given each action one step later (the first twice). Both draw a lag, so their random
    # numbers stay alike.
    late, now = go1(4, "[4,4]"), go1(4, "[0,0]")
    gen = torch.Generator().manual_seed(0)
    actions = [torch.rand(4, 12, generator=gen) * 0.6 - 0.3 for _ in range(25)]
    for t, action in enumerate(actions):
        late.step(action)
        now.step(actions[max(t - 1, 0)])
        assert torch.equal(late.sim.qpos, now.sim.qpos), t
        assert torch.equal(late.sim.qvel, now.sim.qvel), t
    late.close(), now.close()


def test_a_resumed_env_applies_the_controls_the_original_would_have():
    env = go1(4, "[3,9]")
    gen = torch.Generator().manual_seed(1)
    for _ in range(5):
        env.step(torch.rand(4, 12, generator=gen) * 0.6 - 0.3)
    twin = make_env("go1-flat", num_envs=4, seed=7,
                    overrides=[*BASE, "env.actions.delay=[3,9]"])
    twin.resume_from(env.get_state())
    twin.reset()
    for _ in range(5):
        action = torch.rand(4, 12, generator=gen) * 0.6 - 0.3
        env.step(action), twin.step(action)
        assert torch.equal(twin.task.controls, env.task.controls)
        assert torch.equal(twin.sim.qpos, env.sim.qpos)
    env.close(), twin.close()


def test_lags_are_drawn_per_env_within_the_range_and_again_at_each_reset():
    env = go1(64, "[2,6]")
    delay = env.task.actuation.delay
    first = delay.lag.clone()
    assert first.min() >= 2 and first.max() <= 6 and len(first.unique()) == 5
    env.step(torch.zeros(64, 12))
    mask = torch.zeros(64, dtype=torch.bool)
    mask[:32] = True
    env.task.reset(mask, env.task.rng)
    assert torch.equal(delay.lag[32:], first[32:])
    assert not torch.equal(delay.lag[:32], first[:32])
    assert delay.fresh[:32].all() and not delay.fresh[32:].any()
    env.close()


@pytest.mark.parametrize("delay", [[-1, 2], [3, 1]])
def test_a_delay_range_out_of_order_is_one_line(delay):
    with pytest.raises(Exception, match=r"0 <= low <= high"):
        go1(2, json.dumps(delay))


def test_play_sets_a_latency_or_a_command_and_the_export_states_the_latency(tmp_path):
    runner = CliRunner()
    env = {"LAB_LOGS_DIR": str(tmp_path), "COLUMNS": "300"}
    trained = runner.invoke(app, ["train", "--task", "go1-flat", "--framework", "rsl_rl",
                                  "--num-envs", "8", "--max-iterations", "1",
                                  "--set", "env.actions.delay=[2,6]",
                                  "--set", "env.episode_length_s=1"], env=env)
    assert trained.exit_code == 0, trained.output
    played = runner.invoke(app, ["play", "--last", "--episodes", "2", "--num-envs", "2",
                                 "--set", "env.actions.delay=[0,12]",
                                 "--set", "env.observations.joint_vel.delay=[0,2]",
                                 "--set", "env.commands.base_velocity.lin_vel_x=[0.5,0.5]"],
                            env=env)
    assert played.exit_code == 0, played.output
    exported = runner.invoke(app, ["export", "onnx", "--last"], env=env)
    assert exported.exit_code == 0, exported.output
    (meta,) = tmp_path.glob("rsl_rl/go1-flat/*/exported/policy.onnx.json")
    assert json.loads(meta.read_text())["deployment"]["actuator_delay_s"] == [0.01, 0.03]
    wrong = runner.invoke(app, ["play", "--last", "--set", "env.actions.scale=1"], env=env)
    assert wrong.exit_code == 2
    assert "env.actions.delay, env.commands.*.*, env.observations.*.delay" in wrong.output
    removed = runner.invoke(app, ["play", "--last", "--set", "env.commands.base_velocity=null"],
                            env=env)
    assert removed.exit_code == 2 and "cannot change a run" in removed.output
