"""`--task gym:<id>`: gymnasium's vector envs behind LabVecEnv's interface, trained, played and
exported by every framework like a lab task."""

from __future__ import annotations

import io
import json
from contextlib import closing

import numpy as np
import onnxruntime as ort
import pytest
import torch
from rich.console import Console

from labcli.envs import metrics
from labcli.envs.gym_bridge import GymVecEnv
from labcli.envs.make import make_env
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.runs import training
from labcli.runs.export import Format, export
from labcli.runs.play import play

TASK = "gym:InvertedPendulum-v5"
# Tiny agents: the API is under test here, learning in test_sb3_solves_inverted_pendulum.
SMALL = {
    "sb3": ["agent.n_steps=16", "agent.batch_size=32", "agent.n_epochs=1"],
    "rsl_rl": ["agent.num_steps_per_env=16", "agent.num_learning_epochs=1",
               "agent.num_mini_batches=1"],
    "skrl": ["agent.rollouts=16", "agent.learning_epochs=1", "agent.mini_batches=1"],
}


def make(num_envs: int = 4, **cfg) -> GymVecEnv:
    spec = registry.get_task(TASK)
    return make_env(spec, spec.config_class(num_envs=num_envs, **cfg))


def test_steps_like_a_lab_env():
    with closing(make(max_episode_steps=3)) as env:
        assert env.single_action_space.shape == (1,) and env.single_observation_space.shape == (4,)
        obs, _ = env.reset(seed=0)
        assert isinstance(obs, torch.Tensor) and obs.shape == (4, 4) and obs.dtype == torch.float32
        for _ in range(3):  # zero force keeps the pole up for 3 steps: the time-out ends them
            obs, reward, terminated, truncated, info = env.step(torch.zeros(4, 1))
        assert reward.shape == (4,) and reward.dtype == torch.float32
        assert truncated.all() and not terminated.any()
        # Same-step autoreset: obs is the next episode's first, final_obs the true last one.
        assert not torch.allclose(info["final_obs"], obs)
        assert info["lab_episode"]["l"].tolist() == [3] * 4
        assert info["lab_episode"]["r"].tolist() == [3.0] * 4
        stats = env.pop_stats()
        assert stats[metrics.EPISODES] == 4 and stats[metrics.MEAN_RETURN] == 3.0
        assert stats[metrics.SUCCESS_RATE] == 0.0  # below InvertedPendulum's threshold of 950
        assert env.pop_stats() == {}


def test_actions_in_minus_one_one_span_the_action_space():
    with closing(make(num_envs=2)) as env:
        env.reset(seed=0)
        env.step(torch.tensor([[1.0], [-0.5]]))
        ctrl = [sub.unwrapped.data.ctrl[0] for sub in env._vec.envs]
        assert ctrl == pytest.approx([3.0, -1.5])  # InvertedPendulum's bounds are ±3


def test_terminations_are_not_time_outs():
    with closing(make(num_envs=2)) as env:
        env.reset(seed=0)
        for _ in range(200):
            _, _, terminated, truncated, info = env.step(torch.ones(2, 1))
            if terminated.any():
                break
        assert terminated.any() and not truncated.any()
        assert info["terminations"][terminated].all()


@pytest.mark.parametrize("framework", ["sb3", "rsl_rl", "skrl"])
def test_trains_plays_and_exports_with_every_framework(tmp_path, framework):
    outcome = training.train(TASK, framework, num_envs=4, max_iterations=2,
                             overrides=SMALL[framework], logs_dir=tmp_path,
                             console=Console(file=io.StringIO()), command=["lab", "test"])
    assert outcome.summary["state"] == "finished"
    assert outcome.summary["steps"] == 2 * 16 * 4
    manifest = json.loads((outcome.run.dir / "run.json").read_text())
    assert manifest["task"] == TASK and manifest["backend"] == "gymnasium"

    _, eps = play(episodes=2, run_dir=outcome.run.dir)
    assert len(eps.returns) == 2 and all(r > 0 for r in eps.returns)

    result = export(Format.onnx, run_dir=outcome.run.dir)
    meta = json.loads(result.metadata.read_text())
    assert meta["output"]["actions"][0]["command"] == "-3 + (action + 1) / 2 * 6"
    obs = np.random.default_rng(0).normal(size=(5, 4)).astype(np.float32)
    actions = ort.InferenceSession(str(result.path)).run(None, {"obs": obs})[0]
    assert actions.shape == (5, 1) and np.all(np.abs(actions) <= 1.0)


@pytest.mark.parametrize("name, phrases", [
    ("gym:InvertedPendulm-v5", ["unknown gymnasium env 'InvertedPendulm-v5'",
                                "did you mean 'gym:InvertedPendulum-v5'"]),
    ("gym:CartPole-v1", ["action space Discrete(2)", "continuous, bounded actions"]),
])
def test_unknown_ids_and_unsupported_spaces_are_lab_errors(name, phrases):
    with pytest.raises(LabError) as info:
        spec = registry.get_task(name)
        make_env(spec, spec.config_class(num_envs=2))
    for phrase in phrases:
        assert phrase in str(info.value)


def test_gym_tasks_refuse_the_warp_backend():
    spec = registry.get_task(TASK)
    with pytest.raises(LabError, match="not on the 'warp' backend"):
        make_env(spec, spec.config_class(num_envs=2), backend="warp")


@pytest.mark.slow
def test_sb3_solves_inverted_pendulum_with_the_gym_defaults(tmp_path):
    """rl_zoo3-like defaults reach the id's reward threshold (950) within 100 iterations
    (205k steps; ~70k were needed in docs/benchmarks.md's runs)."""
    outcome = training.train(TASK, "sb3", max_iterations=100, logs_dir=tmp_path,
                             console=Console(file=io.StringIO()), command=["lab", "test"])
    assert outcome.summary["mean_return"] >= 950, outcome.summary
