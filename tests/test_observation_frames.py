"""Observation terms' `history_length` and `delay` (labcli/envs/mdp/frames.py), against the
actions the test itself sent: go1-flat's `actions` term is the last action, so its k-th older
frame is the action of k steps before, and an episode's first frame is its zero action."""

from __future__ import annotations

import importlib.util
import io

import numpy as np
import pytest
import torch
from conftest import needs_menagerie
from rich.console import Console

from labcli.gym import make_env
from labcli.sim2sim import PlainLoop

pytestmark = needs_menagerie("unitree_go1")  # go1-flat's robot
NUM_ENVS, ACTIONS = 8, 12
CUDA = pytest.param("warp", marks=[pytest.mark.gpu, pytest.mark.skipif(
    not (torch.cuda.is_available() and importlib.util.find_spec("mujoco_warp")),
    reason='needs a CUDA GPU and MuJoCo Warp (pip install -e ".[warp]")')])


def _env(backend: str, *settings: str, num_envs: int = NUM_ENVS):
    device = "cuda" if backend == "warp" else "cpu"
    return make_env("go1-flat", num_envs, backend=backend, device=device, overrides=[
        "env.observation_noise=false", "env.events.push_robot=null", *settings])


def _actions(steps: int, num_envs: int = NUM_ENVS) -> torch.Tensor:
    generator = torch.Generator().manual_seed(3)
    return torch.rand(steps, num_envs, ACTIONS, generator=generator) * 2 - 1


def _action_columns(env, frames: int) -> list[slice]:
    """The `actions` term's columns of each frame, oldest first."""
    first = env.observation_names.index(f"actions.{env.action_names[0]}" if frames == 1 else
                                        f"actions.{env.action_names[0]}@t-{frames - 1}")
    return [slice(first + k * ACTIONS, first + (k + 1) * ACTIONS) for k in range(frames)]


def _seen(backend: str, steps: int, *settings: str, frames: int = 1, num_envs: int = NUM_ENVS):
    """The sent actions and, per step (the reset's first), each frame of the actions term."""
    env = _env(backend, *settings, num_envs=num_envs)
    columns = _action_columns(env, frames)
    obs, _ = env.reset(seed=0)
    seen = [[obs[:, c].cpu() for c in columns]]
    sent = _actions(steps, num_envs)
    for action in sent:
        obs, *_ = env.step(action.to(env.device))
        seen.append([obs[:, c].cpu() for c in columns])
    env.close()
    return sent, seen


def _sent_before(sent: torch.Tensor, step: int, age: int) -> torch.Tensor:
    """The action in force `age` steps before `step` (step 0: the reset; before it, zeros)."""
    return sent[step - age - 1] if step - age >= 1 else torch.zeros_like(sent[0])


@pytest.mark.parametrize("backend", ["cpu", CUDA])
def test_a_history_holds_the_last_frames_oldest_first(backend):
    env = _env(backend, "env.observations.actions.history_length=3")
    assert env.observation_names[-3 * ACTIONS].endswith("@t-2")
    assert env.observation_names[-1] == f"actions.{env.action_names[-1]}"
    assert env.single_observation_space.shape == (48 + 2 * ACTIONS,)
    env.close()
    sent, seen = _seen(backend, 5, "env.observations.actions.history_length=3", frames=3)
    for step, frames in enumerate(seen):
        for k, frame in enumerate(frames):  # k = 0: the oldest, two steps before
            torch.testing.assert_close(frame, _sent_before(sent, step, 2 - k).float())


@pytest.mark.parametrize("backend", ["cpu", CUDA])
def test_a_delayed_term_shows_the_frame_of_its_lag_before(backend):
    sent, seen = _seen(backend, 5, "env.observations.actions.delay=[2,2]")
    for step, (frame,) in enumerate(seen):
        torch.testing.assert_close(frame, _sent_before(sent, step, 2).float())
    sent, seen = _seen(backend, 5, "env.observations.actions.delay=[1,1]",
                       "env.observations.actions.history_length=2", frames=2)
    for step, (older, newer) in enumerate(seen):
        torch.testing.assert_close(older, _sent_before(sent, step, 2).float())
        torch.testing.assert_close(newer, _sent_before(sent, step, 1).float())


def test_each_env_draws_its_lag_from_the_range():
    steps, envs = 6, 64
    sent, seen = _seen("cpu", steps, "env.observations.actions.delay=[0,3]", num_envs=envs)
    lags = []
    for env in range(envs):
        # The lag that explains every step's frame of this env.
        fits = [lag for lag in range(4) if all(
            torch.equal(frames[0][env], _sent_before(sent, step, lag)[env].float())
            for step, frames in enumerate(seen))]
        assert len(fits) == 1, (env, fits)
        lags.append(fits[0])
    assert set(lags) == {0, 1, 2, 3}


def test_an_episode_starts_its_frames_again():
    """Episodes of 0.1 s (5 steps) end together: the next episode's first input holds its own
    first frame (the zero action) in every slot, not the last episode's."""
    settings = ("env.observations.actions.history_length=3", "env.episode_length_s=0.1")
    sent, seen = _seen("cpu", 7, *settings, frames=3)
    for frame in seen[5]:
        assert not frame.any()
    torch.testing.assert_close(seen[4][1], sent[2].float())  # before the end, the history
    torch.testing.assert_close(seen[6][2], sent[5].float())
    torch.testing.assert_close(seen[6][1], torch.zeros_like(sent[0]))


def test_the_plain_loop_keeps_the_frames_the_export_describes(tmp_path):
    """PlainLoop (labcli/sim2sim.py) builds a history from the export's `history_length`, and
    `lab sim2sim` checks such an export."""
    from labcli.runs import closed_loop, export, training

    outcome = training.train(
        "go1-flat", "rsl_rl", num_envs=4, max_iterations=1, logs_dir=tmp_path,
        console=Console(file=io.StringIO()), command=["lab", "test"],
        overrides=["agent.num_steps_per_env=2", "env.observations.joint_pos.history_length=3",
                   "env.observations.base_ang_vel.delay=[0,2]", "env.episode_length_s=1"])
    result = export.export("onnx", run_dir=outcome.run.dir)
    # lab's side of the check without the sensor's lag, as the plain loop has none
    assert closed_loop.check(run_dir=outcome.run.dir, episodes=2).passed
    loop = PlainLoop(result.path)
    terms = {t["term"]: t for t in loop.meta["deployment"]["observations"]}
    assert terms["joint_pos"]["history_length"] == 3
    assert terms["base_ang_vel"]["training_delay_steps"] == [0, 2]
    start, end = terms["joint_pos"]["columns"]
    assert end - start == 3 * ACTIONS
    index = list(terms).index("joint_pos")
    loop.reset(loop.model.qpos0.copy(), np.zeros(loop.model.nv))
    command = np.zeros(3)
    read = []
    for qpos_shift in (0.0, 0.1, 0.2, 0.3):
        loop.data.qpos[7:] = loop.model.qpos0[7:] + qpos_shift
        read.append(loop.terms[index](command))
        obs = loop.observe(command)
    np.testing.assert_allclose(obs[start:end], np.concatenate(read[1:]), rtol=1e-6)
