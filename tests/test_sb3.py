"""The SB3 plugin with the real library at small sizes: adapter, training, checkpoints, policy."""

from __future__ import annotations

import io
import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest
import torch
from lab_sb3.adapter import Sb3VecEnv
from lab_sb3.framework import Sb3Framework, normalizer_path, read_normalizer
from lab_sb3.plugin import SPEC
from rich.console import Console
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

from labcli import testing
from labcli.envs.env import LabVecEnv
from labcli.errors import LabError
from labcli.plugins.policy import ObsNormalizer
from labcli.runs import checkpoints, rundir, training

NUM_ENVS = 4
N_STEPS = 8
PER_ITERATION = NUM_ENVS * N_STEPS
# VecNormalize on (SB3's default; cartpole's own sb3 defaults turn it off).
SMALL = [f"agent.n_steps={N_STEPS}", "agent.batch_size=16", "agent.n_epochs=2",
         "agent.net_arch=[16,16]", "agent.normalize_obs=true"]


make_env = testing.make_env


def train(tmp_path: Path, iterations: int, sets: list[str] = (), **kwargs) -> training.TrainOutcome:
    return testing.train_small("sb3", tmp_path, iterations, [*SMALL, *sets], **kwargs)


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> training.TrainOutcome:
    """One short run with VecNormalize on, shared by read-only tests."""
    return train(tmp_path_factory.mktemp("logs"), 3, ["agent.save_interval=2"])


def test_adapter_hands_sb3_the_true_last_observation_on_time_outs():
    env = Sb3VecEnv(make_env(episode_length_s=0.1))  # 5 steps of 0.02 s
    obs = env.reset()
    assert obs.shape == (NUM_ENVS, 4) and obs.dtype == np.float32
    for step in range(5):
        env.step_async(np.zeros((NUM_ENVS, 1), dtype=np.float32))
        obs, reward, done, infos = env.step_wait()
        assert reward.shape == (NUM_ENVS,) and done.dtype == bool
        assert done.all() == (step == 4)
    for i, info in enumerate(infos):
        assert info["TimeLimit.truncated"] is True  # SB3 bootstraps these
        last = info["terminal_observation"]
        assert last.shape == (4,) and not np.allclose(last, obs[i])
        assert info["episode"]["l"] == 5


def test_adapter_marks_terminations_as_not_truncated():
    env = Sb3VecEnv(make_env(cart_bound=0.1, reset_cart_pos=(0.5, 0.5)))  # out of bounds at once
    env.reset()
    env.step_async(np.zeros((NUM_ENVS, 1), dtype=np.float32))
    _, _, done, infos = env.step_wait()
    assert done.all() and not any(info["TimeLimit.truncated"] for info in infos)


def test_training_writes_run_dir_checkpoints_normalizer_and_tensorboard(trained):
    run_dir = trained.run.dir
    assert sorted(p.name for p in run_dir.glob("model_*.zip")) == ["model_2.zip", "model_3.zip"]
    assert sorted(p.name for p in run_dir.glob("vecnormalize_*")) == [
        "vecnormalize_2.json", "vecnormalize_3.json"]
    assert not list(run_dir.glob(".tmp_*"))
    for name in (rundir.ENV_PARAMS, rundir.AGENT_PARAMS, rundir.COMMAND, rundir.MANIFEST):
        assert (run_dir / name).is_file()
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == "finished" and summary["checkpoint"] == "model_3.zip"
    assert summary["iterations"] == 3 and summary["steps"] == 3 * PER_ITERATION
    assert json.loads((run_dir / rundir.MANIFEST).read_text())["state"] == "finished"
    assert list(run_dir.glob("events.out.tfevents.*"))


def test_policy_includes_the_saved_normalizer(trained):
    checkpoint = trained.run.dir / "model_3.zip"
    policy = testing.load_policy("sb3", checkpoint, make_env())
    assert isinstance(policy.normalizer, ObsNormalizer)
    # SB3's own loader (trusted here: this test wrote the file) agrees with lab's.
    model = PPO.load(checkpoint, device="cpu")
    saved = read_normalizer(normalizer_path(checkpoint))
    norm = VecNormalize(Sb3VecEnv(make_env()), clip_obs=saved["clip_obs"],
                        epsilon=saved["epsilon"])
    norm.obs_rms = saved["obs_rms"]
    obs = np.random.default_rng(0).normal(size=(64, 4)).astype(np.float32) * [1, 1, 3, 10]
    expected, _ = model.predict(norm.normalize_obs(obs), deterministic=True)
    with torch.no_grad():
        actual = policy(torch.as_tensor(obs, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(actual, np.clip(expected, -1, 1), atol=1e-5)


def test_policy_without_normalization(tmp_path):
    outcome = train(tmp_path, 1, ["agent.normalize_obs=false"])
    assert not list(outcome.run.dir.glob("vecnormalize_*"))
    policy = testing.load_policy("sb3", outcome.run.dir / "model_1.zip", make_env())
    assert isinstance(policy.normalizer, torch.nn.Identity)


def test_resume_continues_iterations_steps_and_normalizer(tmp_path):
    first = train(tmp_path, 2)
    second = train(tmp_path, 4, checkpoint=checkpoints.LATEST)
    assert second.run.dir == first.run.dir
    assert second.summary["iterations"] == 4 and second.summary["steps"] == 4 * PER_ITERATION
    assert PPO.load(first.run.dir / "model_4.zip").num_timesteps == 4 * PER_ITERATION
    counts = [read_normalizer(first.run.dir / f"vecnormalize_{i}.json")["obs_rms"].count
              for i in (2, 4)]
    assert counts[1] > counts[0] + PER_ITERATION  # the resumed normalizer kept its statistics


def test_stop_mid_rollout_leaves_a_loadable_checkpoint(tmp_path, monkeypatch):
    original = LabVecEnv.step
    calls = 0

    def step(self, actions):
        nonlocal calls
        calls += 1
        if calls == N_STEPS + 3:  # mid-way through the second iteration's rollout
            os.kill(os.getpid(), signal.SIGINT)
        return original(self, actions)

    monkeypatch.setattr(LabVecEnv, "step", step)
    outcome = train(tmp_path, 5)
    assert outcome.summary["state"] == "interrupted"
    checkpoints = sorted(outcome.run.dir.glob("model_*.zip"))
    assert checkpoints, "an interrupted run keeps a checkpoint"
    testing.load_policy("sb3", checkpoints[-1], make_env())
    assert json.loads((outcome.run.dir / rundir.MANIFEST).read_text())["state"] == "interrupted"


@pytest.mark.parametrize("content", [b"not a zip", b""])
def test_corrupt_checkpoints_raise_lab_error(tmp_path, content):
    path = tmp_path / "model_7.zip"
    path.write_bytes(content)
    with pytest.raises(LabError) as err:
        Sb3Framework(SPEC).load_policy(path, make_env(), SPEC.agent_config_class())
    assert "model_7.zip" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.slow
def test_cartpole_defaults_reach_success(tmp_path):
    from labcli.runs import play

    outcome = training.train("cartpole", "sb3", logs_dir=tmp_path,
                             console=Console(file=io.StringIO()))
    assert outcome.summary["wall_time_s"] < 120
    _, episodes = play.play(run_dir=outcome.run.dir, episodes=100)
    assert episodes.success_rate >= 0.95
