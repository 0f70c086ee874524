"""The skrl plugin with the real library at small sizes: adapter, training, checkpoints, policy."""

from __future__ import annotations

import io
import json
import os
import signal
from pathlib import Path
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
import torch
from lab_skrl.adapter import SkrlEnv
from lab_skrl.config import SkrlPPOConfig
from lab_skrl.framework import META, SkrlFramework, _collect_and_update, make_agent
from lab_skrl.plugin import SPEC
from rich.console import Console
from runfiles import remanifest, snapshot_of
from skrl.resources.preprocessors.torch import RunningStandardScaler

from labcli import testing
from labcli.envs.env import LabVecEnv
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.plugins.policy import ObsNormalizer
from labcli.runs import checkpoints, rundir, training

NUM_ENVS = 4
ROLLOUTS = 8
PER_ITERATION = NUM_ENVS * ROLLOUTS
SMALL = [f"agent.rollouts={ROLLOUTS}", "agent.learning_epochs=2", "agent.mini_batches=2",
         "agent.hidden_sizes=[16,16]"]


make_env = testing.make_env


def train(tmp_path: Path, iterations: int, sets: list[str] = (), **kwargs) -> training.TrainOutcome:
    return testing.train_small("skrl", tmp_path, iterations, [*SMALL, *sets], **kwargs)


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> training.TrainOutcome:
    """One short run with observation normalization on (the default), shared by read-only tests."""
    return train(tmp_path_factory.mktemp("logs"), 3, ["agent.save_interval=2"])


def test_registered_with_its_adapter():
    fw = registry.get_framework("skrl").load()
    assert isinstance(fw, SkrlFramework)
    adapter = registry.get_wrapper("skrl.adapter")
    assert adapter.framework == "skrl"
    assert [step.spec for step in fw.pipeline(fw.agent_config())] == [adapter]


def test_adapter_shapes_dtypes_and_time_outs():
    env = SkrlEnv(make_env(episode_length_s=0.1))  # 5 steps of 0.02 s
    assert env.num_envs == NUM_ENVS
    assert env.observation_space.shape == (4,) and env.action_space.shape == (1,)
    assert env.state_space is None and env.state() is None
    obs, _ = env.reset()
    assert isinstance(obs, torch.Tensor) and obs.shape == (NUM_ENVS, 4)
    for step in range(5):
        obs, reward, terminated, truncated, info = env.step(torch.zeros(NUM_ENVS, 1))
        assert obs.dtype == torch.float32 and obs.shape == (NUM_ENVS, 4)
        assert reward.dtype == torch.float32 and reward.shape == (NUM_ENVS, 1)
        assert terminated.dtype == torch.bool and terminated.shape == (NUM_ENVS, 1)
        assert truncated.dtype == torch.bool and truncated.shape == (NUM_ENVS, 1)
        assert not terminated.any()
        assert truncated.all() == (step == 4)
    # reset in the same step: the true last observation is kept for the value bootstrap
    assert not torch.equal(info["final_obs"], obs)


def test_adapter_keeps_terminations_apart_from_time_outs():
    env = SkrlEnv(make_env(cart_bound=0.1, reset_cart_pos=(0.5, 0.5)))  # out of bounds at once
    env.reset()
    _, _, terminated, truncated, _ = env.step(torch.zeros(NUM_ENVS, 1))
    assert terminated.all() and not truncated.any()


class RecordingAgent:
    """Stands in for skrl's PPO to see what the training loop hands it."""

    state_space = None  # a task without critic observations: no states

    def __init__(self):
        self.transitions: list[dict] = []

    def pre_interaction(self, **kwargs) -> None:
        pass

    def act(self, obs, states, **kwargs):
        return torch.zeros(obs.shape[0], 1), {}

    def record_transition(self, **kwargs) -> None:
        self.transitions.append(kwargs)

    def post_interaction(self, **kwargs) -> None:
        pass


def test_time_outs_bootstrap_from_the_true_last_observation():
    env = SkrlEnv(make_env(episode_length_s=0.1))  # time-out after 5 steps
    agent = RecordingAgent()
    ctx = SimpleNamespace(cfg=SkrlPPOConfig(rollouts=8, max_iterations=1))
    obs, _ = env.reset()
    _collect_and_update(agent, env, obs, ctx, 1)
    assert len(agent.transitions) == 8
    ended = agent.transitions[4]
    assert ended["truncated"].all() and not ended["terminated"].any()
    # the next step starts from the reset observation, but skrl bootstraps from the last one
    assert not torch.equal(ended["next_observations"], agent.transitions[5]["observations"])
    ongoing = agent.transitions[3]
    torch.testing.assert_close(ongoing["next_observations"], ended["observations"])


def test_agent_bootstraps_on_time_outs():
    env = SkrlEnv(make_env())
    agent = make_agent(SkrlPPOConfig(), env, "cpu", Path("unused"))
    assert agent.cfg.time_limit_bootstrap


def test_training_writes_checkpoints_and_summary(trained):
    run_dir = trained.run.dir
    assert sorted(p.name for p in run_dir.glob("model_*.pt")) == ["model_2.pt", "model_3.pt"]
    assert not list(run_dir.glob(".tmp_*"))
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == "finished"
    assert summary["iterations"] == 3 and summary["steps"] == 3 * PER_ITERATION
    assert summary["checkpoint"] == "model_3.pt"
    saved = torch.load(run_dir / "model_3.pt", weights_only=True)
    assert {"policy", "value", "optimizer", "observation_preprocessor"} <= set(saved)
    assert saved[META]["steps"] == 3 * PER_ITERATION
    assert list(run_dir.glob("events.out.tfevents.*"))
    assert not (run_dir / "checkpoints").exists()  # skrl's own checkpointer stays off


def test_training_keeps_skrl_quiet(tmp_path, capfd):
    train(tmp_path, 1)
    out, err = capfd.readouterr()
    assert "skrl" not in out + err


def test_policy_includes_the_trained_normalizer(trained):
    checkpoint = trained.run.dir / "model_3.pt"
    env = make_env()
    policy = testing.load_policy("skrl", checkpoint, env)
    assert isinstance(policy.normalizer, ObsNormalizer)

    saved = torch.load(checkpoint, weights_only=True)
    scaler = RunningStandardScaler(4, clip_threshold=saved[META]["obs_clip"], device="cpu")
    scaler.load_state_dict(saved["observation_preprocessor"])
    assert scaler.running_mean.abs().sum() > 0  # trained, not the initial zeros

    obs = torch.randn(64, 4) * torch.tensor([1.0, 1.0, 3.0, 10.0])
    with torch.no_grad():
        expected = policy.actor(scaler(obs)).clamp(-1.0, 1.0)  # what skrl's agent acts on
        without = policy.actor(obs).clamp(-1.0, 1.0)
        actual = policy(obs)
    torch.testing.assert_close(actual, expected, atol=1e-5, rtol=1e-5)
    assert not torch.allclose(actual, without, atol=1e-3)
    torch.testing.assert_close(policy(obs), actual)  # deterministic


def test_policy_without_normalization(tmp_path):
    outcome = train(tmp_path, 1, ["agent.normalize_obs=false"])
    policy = testing.load_policy("skrl", outcome.run.dir / "model_1.pt", make_env())
    assert isinstance(policy.normalizer, torch.nn.Identity)


def test_resume_continues_iterations_optimizer_and_normalizer(tmp_path):
    first = train(tmp_path, 2)
    before = torch.load(first.run.dir / "model_2.pt", weights_only=True)
    second = train(tmp_path, 4, checkpoint=checkpoints.LATEST)
    assert second.run.dir == first.run.dir
    assert second.summary["iterations"] == 4 and second.summary["steps"] == 4 * PER_ITERATION
    after = torch.load(first.run.dir / "model_4.pt", weights_only=True)
    # Adam's step count carries on: 2 updates per iteration (epochs × mini-batches)
    updates_per_iteration = 2 * 2
    assert int(after["optimizer"]["state"][0]["step"]) == 4 * updates_per_iteration
    assert int(before["optimizer"]["state"][0]["step"]) == 2 * updates_per_iteration
    count = "current_count"
    assert after["observation_preprocessor"][count] > before["observation_preprocessor"][count]


@pytest.mark.parametrize("steps", ["x", -1, 1.5, True])
def test_a_checkpoint_whose_steps_are_not_a_count_is_refused_before_anything_is_written(
        tmp_path, steps):
    run = train(tmp_path, 2).run.dir
    saved = torch.load(run / "model_2.pt", weights_only=True)
    saved[META]["steps"] = steps
    torch.save(saved, run / "model_2.pt")
    remanifest(run, 2)  # as a hand edit would leave it: a whole checkpoint
    before = snapshot_of(tmp_path)
    with pytest.raises(LabError, match=f"model_2.pt records {steps!r} env steps, not a count"):
        train(tmp_path, 4, checkpoint=checkpoints.LATEST)
    assert snapshot_of(tmp_path) == before


def test_stop_mid_rollout_leaves_a_loadable_checkpoint(tmp_path, monkeypatch):
    original = LabVecEnv.step
    calls = 0

    def step(self, actions):
        nonlocal calls
        calls += 1
        if calls == ROLLOUTS + 3:  # mid-way through the second iteration's rollout
            os.kill(os.getpid(), signal.SIGINT)
        return original(self, actions)

    monkeypatch.setattr(LabVecEnv, "step", step)
    outcome = train(tmp_path, 5)
    assert outcome.summary["state"] == "interrupted"
    assert outcome.summary["iterations"] == 1
    assert calls == ROLLOUTS + 3  # stopped at once, not at the end of the rollout
    checkpoint = outcome.run.dir / "model_1.pt"
    assert checkpoint.is_file()
    testing.load_policy("skrl", checkpoint, make_env())


def test_mismatched_sizes_raise_lab_error(trained):
    other = SimpleNamespace(
        single_observation_space=gym.spaces.Box(-np.inf, np.inf, (5,), np.float32),
        single_action_space=gym.spaces.Box(-1.0, 1.0, (1,), np.float32),
        task_spec=SimpleNamespace(name="other"))
    with pytest.raises(LabError) as err:
        testing.load_policy("skrl", trained.run.dir / "model_3.pt", other)
    assert "observation size 4" in str(err.value) and "has 5" in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("content", [b"not a checkpoint", None, "foreign"])
def test_unreadable_checkpoints_raise_lab_error(tmp_path, content):
    path = tmp_path / "model_7.pt"
    if content == "foreign":
        torch.save({"weights": torch.zeros(3)}, path)
    elif content is not None:
        path.write_bytes(content)
    with pytest.raises(LabError) as err:
        SkrlFramework(SPEC).load_policy(path, make_env(), SPEC.agent_config_class())
    assert "model_7.pt" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.slow
def test_cartpole_defaults_reach_success(tmp_path):
    outcome = training.train("cartpole", "skrl", logs_dir=tmp_path,
                             console=Console(file=io.StringIO()))
    assert outcome.summary["success_rate"] >= 0.95
    assert outcome.summary["wall_time_s"] < 120
