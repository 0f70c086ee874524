"""The RSL-RL plugin with the real library at small sizes: adapter, training, checkpoints."""

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
from lab_rsl_rl.adapter import OBS_GROUP, RslRlVecEnv
from lab_rsl_rl.config import RslRlPpoConfig
from lab_rsl_rl.framework import INFO_KEY, RslRlFramework, runner_config
from lab_rsl_rl.plugin import SPEC
from rich.console import Console
from rsl_rl.models import MLPModel
from tensordict import TensorDict

from labcli import testing
from labcli.envs.env import LabVecEnv
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.plugins.policy import ObsNormalizer
from labcli.runs import checkpoints, rundir, training

NUM_ENVS = 4
STEPS = 8  # num_steps_per_env
PER_ITERATION = NUM_ENVS * STEPS
EPOCHS, MINI_BATCHES = 2, 2
SMALL = [f"agent.num_steps_per_env={STEPS}", f"agent.num_learning_epochs={EPOCHS}",
         f"agent.num_mini_batches={MINI_BATCHES}", "agent.actor_hidden_dims=[16,16]",
         "agent.critic_hidden_dims=[16,16]"]


make_env = testing.make_env


def train(tmp_path: Path, iterations: int, sets: list[str] = (), **kwargs) -> training.TrainOutcome:
    return testing.train_small("rsl_rl", tmp_path, iterations, [*SMALL, *sets], **kwargs)


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> training.TrainOutcome:
    """One short run with observation normalization on (the default), shared by read-only tests."""
    return train(tmp_path_factory.mktemp("logs"), 3, ["agent.save_interval=2"])


def test_registered_with_its_adapter():
    fw = registry.get_framework("rsl_rl").load()
    assert isinstance(fw, RslRlFramework)
    adapter = registry.get_wrapper("rsl_rl.adapter")
    assert adapter.framework == "rsl_rl"
    assert [step.spec for step in fw.pipeline(fw.agent_config())] == [adapter]


def test_agent_config_maps_onto_the_runner_schema():
    cfg = RslRlPpoConfig(gamma=0.9, clip_param=0.1, actor_hidden_dims=[8], activation="tanh",
                         init_noise_std=0.4, empirical_normalization=False, desired_kl=None)
    out = runner_config(cfg)
    assert out["algorithm"]["gamma"] == 0.9 and out["algorithm"]["clip_param"] == 0.1
    assert out["algorithm"]["desired_kl"] is None
    assert out["actor"]["hidden_dims"] == [8] and out["actor"]["activation"] == "tanh"
    assert out["actor"]["distribution_cfg"]["init_std"] == 0.4
    assert out["actor"]["obs_normalization"] is out["critic"]["obs_normalization"] is False
    assert out["obs_groups"] == {"actor": [OBS_GROUP], "critic": [OBS_GROUP]}


def test_the_kl_target_grows_with_the_ranks_unless_told_not_to():
    def target(world_size: int, **settings) -> float | None:
        return runner_config(RslRlPpoConfig(**settings), world_size)["algorithm"]["desired_kl"]

    assert target(1, desired_kl=0.01) == 0.01
    assert target(2, desired_kl=0.01) == 0.02 and target(4, desired_kl=0.01) == 0.04
    assert target(4, desired_kl=0.01, kl_grows_with_ranks=False) == 0.01
    assert target(4, desired_kl=None) is None  # no adaptive learning rate: nothing to scale


def test_adapter_shapes_dtypes_and_time_outs():
    env = RslRlVecEnv(make_env(episode_length_s=0.1))  # 5 steps of 0.02 s
    assert env.num_envs == NUM_ENVS and env.num_actions == 1 and env.max_episode_length == 5
    obs = env.get_observations()
    assert isinstance(obs, TensorDict) and list(obs.keys()) == [OBS_GROUP]
    assert obs[OBS_GROUP].shape == (NUM_ENVS, 4) and obs[OBS_GROUP].dtype == torch.float32
    for step in range(5):
        obs, reward, dones, extras = env.step(torch.zeros(NUM_ENVS, 1))
        assert obs.batch_size == torch.Size([NUM_ENVS])
        assert obs[OBS_GROUP].dtype == torch.float32 and obs[OBS_GROUP].shape == (NUM_ENVS, 4)
        assert reward.dtype == torch.float32 and reward.shape == (NUM_ENVS,)
        assert dones.dtype == torch.bool and dones.shape == (NUM_ENVS,)
        time_outs = extras["time_outs"]
        assert time_outs.dtype == torch.bool and time_outs.shape == (NUM_ENVS,)
        assert dones.all() == time_outs.all() == (step == 4)


def test_adapter_keeps_terminations_apart_from_time_outs():
    env = RslRlVecEnv(make_env(cart_bound=0.1, reset_cart_pos=(0.5, 0.5)))  # out of bounds at once
    _, _, dones, extras = env.step(torch.zeros(NUM_ENVS, 1))
    assert dones.all() and not extras["time_outs"].any()  # terminal: no value bootstrap


def test_training_writes_checkpoints_and_summary(trained):
    run_dir = trained.run.dir
    assert sorted(p.name for p in run_dir.glob("model_*.pt")) == ["model_2.pt", "model_3.pt"]
    assert not list(run_dir.glob(".tmp_*"))
    assert not (run_dir / "git").exists()  # RSL-RL's own logger (git diffs, saves) stays off
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == "finished"
    assert summary["iterations"] == 3 and summary["steps"] == 3 * PER_ITERATION
    assert summary["checkpoint"] == "model_3.pt"
    saved = torch.load(run_dir / "model_3.pt", weights_only=True)
    assert {"actor_state_dict", "critic_state_dict", "optimizer_state_dict"} <= set(saved)
    assert saved["iter"] == 3  # RSL-RL's runner resumes at "iter": the iterations done
    assert list(run_dir.glob("events.out.tfevents.*"))


def test_training_keeps_rsl_rl_quiet(tmp_path, capfd):
    train(tmp_path, 1)
    out, err = capfd.readouterr()
    assert out == ""  # no model dump, no per-iteration report
    assert "Learning iteration" not in err and "Actor Model" not in err


def test_policy_includes_the_trained_normalizer(trained):
    checkpoint = trained.run.dir / "model_3.pt"
    policy = testing.load_policy("rsl_rl", checkpoint, make_env())
    assert isinstance(policy.normalizer, ObsNormalizer)

    # The actor as RSL-RL itself builds and runs it, normalizer inside.
    saved = torch.load(checkpoint, weights_only=True)
    actor_cfg = dict(saved["infos"][INFO_KEY]["actor"])
    assert actor_cfg.pop("class_name") == "MLPModel"
    dummy = TensorDict({OBS_GROUP: torch.zeros(1, 4)}, batch_size=[1])
    model = MLPModel(dummy, {"actor": [OBS_GROUP]}, "actor", 1, **actor_cfg)
    model.load_state_dict(saved["actor_state_dict"])
    model.eval()
    assert model.obs_normalizer.count > 0  # trained, not the initial statistics

    obs = torch.randn(64, 4) * torch.tensor([1.0, 1.0, 3.0, 10.0])
    with torch.no_grad():
        expected = model(TensorDict({OBS_GROUP: obs}, batch_size=[64])).clamp(-1.0, 1.0)
        without = policy.actor(obs).clamp(-1.0, 1.0)
        actual = policy(obs)
    torch.testing.assert_close(actual, expected, atol=1e-5, rtol=1e-5)
    assert not torch.allclose(actual, without, atol=1e-3)
    torch.testing.assert_close(policy(obs), actual)  # deterministic


def test_policy_without_normalization(tmp_path):
    outcome = train(tmp_path, 1, ["agent.empirical_normalization=false"])
    policy = testing.load_policy("rsl_rl", outcome.run.dir / "model_1.pt", make_env())
    assert isinstance(policy.normalizer, torch.nn.Identity)


def test_resume_continues_iterations_optimizer_and_normalizer(tmp_path):
    first = train(tmp_path, 2)
    before = torch.load(first.run.dir / "model_2.pt", weights_only=True)
    second = train(tmp_path, 4, checkpoint=checkpoints.LATEST)
    assert second.run.dir == first.run.dir
    assert second.summary["iterations"] == 4 and second.summary["steps"] == 4 * PER_ITERATION
    after = torch.load(first.run.dir / "model_4.pt", weights_only=True)
    assert after["iter"] == 4
    # Adam's step count carries on: epochs × mini-batches updates per iteration.
    updates = EPOCHS * MINI_BATCHES
    assert int(before["optimizer_state_dict"]["state"][0]["step"]) == 2 * updates
    assert int(after["optimizer_state_dict"]["state"][0]["step"]) == 4 * updates
    # The normalizer has seen every observation of all four iterations.
    count = "obs_normalizer.count"
    assert int(before["actor_state_dict"][count]) == 2 * PER_ITERATION
    assert int(after["actor_state_dict"][count]) == 4 * PER_ITERATION


def test_resume_with_another_network_raises_lab_error(tmp_path):
    train(tmp_path, 1)
    with pytest.raises(LabError) as err:
        train(tmp_path, 2, ["agent.actor_hidden_dims=[8]"], checkpoint=checkpoints.LATEST)
    assert "model_1.pt" in str(err.value) and "\n" not in str(err.value)


def test_stop_mid_rollout_leaves_a_loadable_checkpoint(tmp_path, monkeypatch):
    original = LabVecEnv.step
    calls = 0

    def step(self, actions):
        nonlocal calls
        calls += 1
        if calls == STEPS + 3:  # mid-way through the second iteration's rollout
            os.kill(os.getpid(), signal.SIGINT)
        return original(self, actions)

    monkeypatch.setattr(LabVecEnv, "step", step)
    outcome = train(tmp_path, 5)
    assert outcome.summary["state"] == "interrupted"
    assert outcome.summary["iterations"] == 1
    assert calls == STEPS + 3  # stopped at once, not at the end of the rollout
    checkpoint = outcome.run.dir / "model_1.pt"
    assert checkpoint.is_file() and not (outcome.run.dir / "model_2.pt").exists()
    testing.load_policy("rsl_rl", checkpoint, make_env())


def test_mismatched_sizes_raise_lab_error(trained):
    other = SimpleNamespace(
        single_observation_space=gym.spaces.Box(-np.inf, np.inf, (5,), np.float32),
        single_action_space=gym.spaces.Box(-1.0, 1.0, (1,), np.float32),
        task_spec=SimpleNamespace(name="other"))
    with pytest.raises(LabError) as err:
        testing.load_policy("rsl_rl", trained.run.dir / "model_3.pt", other)
    assert "observation size 4" in str(err.value) and "has 5" in str(err.value)
    assert "\n" not in str(err.value)


def test_a_checkpoint_naming_rsl_rl_s_own_distribution_still_plays(tmp_path, trained):
    saved = torch.load(trained.run.dir / "model_3.pt", weights_only=True)
    distribution = saved["infos"][INFO_KEY]["actor"]["distribution_cfg"]
    assert distribution["class_name"] == "lab_rsl_rl.distribution:GaussianDistribution"
    distribution["class_name"] = "GaussianDistribution"  # as runs of earlier versions of lab
    torch.save(saved, tmp_path / "model_3.pt")
    obs = torch.randn(16, 4)
    fw, cfg = RslRlFramework(SPEC), SPEC.agent_config_class()
    new = fw.load_policy(trained.run.dir / "model_3.pt", make_env(), cfg)
    old = fw.load_policy(tmp_path / "model_3.pt", make_env(), cfg)
    torch.testing.assert_close(old(obs), new(obs))


@pytest.mark.parametrize("content", [b"not a checkpoint", None, "foreign", "plain rsl_rl",
                                     "other class"])
def test_unreadable_checkpoints_raise_lab_error(tmp_path, trained, content):
    path = tmp_path / "model_7.pt"
    saved = torch.load(trained.run.dir / "model_3.pt", weights_only=True)
    if content == "foreign":
        torch.save({"weights": torch.zeros(3)}, path)
    elif content == "plain rsl_rl":  # a runner's own save, without what lab needs to rebuild
        torch.save({**saved, "infos": None}, path)
    elif content == "other class":  # RSL-RL would import and call whatever a class name names
        saved["infos"][INFO_KEY]["actor"]["class_name"] = "builtins:exit"
        torch.save(saved, path)
    elif content is not None:
        path.write_bytes(content)
    with pytest.raises(LabError) as err:
        RslRlFramework(SPEC).load_policy(path, make_env(), SPEC.agent_config_class())
    assert "model_7.pt" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.slow
def test_cartpole_defaults_reach_success(tmp_path):
    from labcli.runs import play  # `lab play`'s library side
    from labcli.runs.bench import time_to_success

    outcome = training.train("cartpole", "rsl_rl", logs_dir=tmp_path,
                             console=Console(file=io.StringIO()))
    # Reached during training (the last iteration's rate alone is ~6 episodes at the defaults:
    # one failure reads 0.8), and judged on 200 episodes of the final policy.
    assert time_to_success(outcome.run.dir, 0.95) is not None
    assert outcome.summary["wall_time_s"] < 120
    _, episodes = play.play(run_dir=outcome.run.dir, episodes=200)
    assert episodes.success_rate >= 0.95


def test_train_play_and_export_without_a_git_executable(tmp_path):
    """RSL-RL imports GitPython, which refused to import without git ("Bad git executable"):
    containers often have none, and lab needs no git state from it."""
    import subprocess
    import sys

    env = {**os.environ, "GIT_PYTHON_GIT_EXECUTABLE": str(tmp_path / "no-git"),
           "LAB_LOGS_DIR": str(tmp_path / "logs")}
    env.pop("GIT_PYTHON_REFRESH", None)
    lab = [sys.executable, "-m", "labcli"]
    for args in (["train", "--task", "cartpole", "--framework", "rsl_rl", "--num-envs", "8",
                  "--max-iterations", "1", "--set", "agent.num_steps_per_env=8"],
                 ["play", "--last", "--episodes", "1"], ["export", "onnx", "--last"]):
        done = subprocess.run([*lab, *args], env=env, capture_output=True, text=True,
                              timeout=300)
        assert done.returncode == 0, done.stderr
        assert "git" not in done.stderr.lower(), done.stderr
