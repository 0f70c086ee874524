"""SB3's SAC and TD3 in lab: what the conformance suite does not reach (a replay buffer that wraps
around, is kept with the newest checkpoint only or meets another env count, a resume during the
warm-up, time-outs in the buffer, a zip plain SB3 loads)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
import torch
from lab_sb3 import offpolicy
from lab_sb3.adapter import Sb3VecEnv
from lab_sb3.framework import memory_path
from oneline import assert_one_line_error
from rich.console import Console
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from typer.testing import CliRunner

from labcli import testing
from labcli.commands.app import app
from labcli.errors import LabError, TrainingDiverged
from labcli.plugins import registry
from labcli.runs import checkpoints

SMALL = testing.SB3_OFF_POLICY


@pytest.mark.parametrize("name", ["sb3_sac", "sb3_td3"])
def test_a_resume_after_the_replay_buffer_wrapped_around_equals_an_unbroken_run(name, tmp_path):
    # 4 envs × 8 steps an iteration into 48 transitions: full after 1.5 iterations. TD3
    # updates its actor every third critic update, so a resume must go on counting them.
    overrides = [*SMALL, "agent.buffer_size=48"]
    if name == "sb3_td3":
        overrides.append("agent.policy_delay=3")
    assert testing.check_resume(name, tmp_path, overrides) == 0.0


def test_a_resume_during_the_warm_up_equals_an_unbroken_run(tmp_path):
    # 100 random steps: the resume after 2 iterations (64 steps) draws the rest of them.
    assert testing.check_resume("sb3_td3", tmp_path, [*SMALL, "agent.learning_starts=100"]) == 0.0


def _trained(tmp_path: Path, name: str = "sb3_sac", sets: tuple[str, ...] = ()) -> Path:
    """The checkpoint of 2 iterations in tmp_path/run."""
    outcome = testing.train_small(name, tmp_path / "run", 2, [*SMALL, *sets])
    return registry.get_framework(name).checkpoint_path(outcome.run.dir, 2)


def _saved(checkpoint: Path) -> dict[str, np.ndarray]:
    with np.load(memory_path(checkpoint), allow_pickle=False) as saved:
        return dict(saved)


def test_a_checkpoint_saves_the_replay_buffer_beside_it(tmp_path):
    checkpoint = _trained(tmp_path)
    saved = _saved(checkpoint)
    # 2 iterations × 8 steps of 4 envs: 16 rows of 4 transitions, written on from row 16.
    assert saved["pos"] == 16 and not saved["full"]
    assert saved["observations"].shape == (16, 4, 4)
    assert memory_path(checkpoint).name == "memory_2.npz"


def test_time_outs_enter_the_buffer_flagged_with_their_true_last_observations(tmp_path):
    # Episodes of 5 steps: every env times out at its fifth step, and starts anew.
    saved = _saved(_trained(tmp_path, sets=(testing.SHORT_EPISODE,)))
    timeouts, dones = saved["timeouts"].astype(bool), saved["dones"].astype(bool)
    assert timeouts.any() and not (timeouts & ~dones).any()
    # What follows a time-out is the next episode's first observation, not its next one.
    step, env = np.argwhere(timeouts[:-1])[0]
    assert not np.array_equal(saved["next_observations"][step, env],
                              saved["observations"][step + 1, env])


def test_only_the_newest_checkpoint_keeps_the_replay_buffer_and_an_older_one_resumes_empty(
        tmp_path, monkeypatch):
    spec = registry.get_framework("sb3_sac")
    outcome = testing.train_small("sb3_sac", tmp_path / "run", 3, [*SMALL, "agent.save_interval=1"])
    run_dir = outcome.run.dir
    found = spec.checkpoints(run_dir)
    assert [c.iteration for c in found] == [1, 2, 3]
    assert [memory_path(c.path).exists() for c in found] == [False, False, True]
    assert all(checkpoints.complete(spec, c) for c in found)
    loaded = buffer_loads(monkeypatch)
    said = io.StringIO()
    resumed = testing.train_small("sb3_sac", tmp_path / "run", 4, SMALL, checkpoint=found[0].path,
                                  console=Console(file=said, width=300))
    assert (loaded["pos"], loaded["full"]) == (0, False)
    assert ("note: model_1.zip holds no replay buffer (only a run's newest checkpoint keeps "
            "it); the resumed run starts with an empty one") in said.getvalue()
    assert resumed.summary["iterations"] == 4
    assert [memory_path(c.path).exists() for c in spec.checkpoints(run_dir)] == [False] * 3 + [True]


def buffer_loads(monkeypatch) -> dict:
    """What the next resume's replay buffer holds once loaded: where it writes next, whether it
    is full, its rewards."""
    loaded = {}
    original = offpolicy.load_memory

    def load(buffer, path):
        original(buffer, path)
        loaded.update(pos=buffer.pos, full=buffer.full, rewards=buffer.rewards.copy())

    monkeypatch.setattr(offpolicy, "load_memory", load)
    return loaded


def test_a_checkpoint_without_its_replay_buffer_is_not_resumed(tmp_path):
    checkpoint = _trained(tmp_path)
    memory_path(checkpoint).unlink()
    with pytest.raises(LabError, match="no complete checkpoint of a sb3_sac run"):
        testing.train_small("sb3_sac", tmp_path / "run", 3, SMALL, checkpoint=checkpoints.LATEST)


def test_a_resume_with_another_env_count_keeps_the_newest_transitions(tmp_path, monkeypatch):
    loaded = buffer_loads(monkeypatch)
    checkpoint = _trained(tmp_path)  # 16 rows of 4 envs: 64 transitions
    saved = _saved(checkpoint)["rewards"]
    # 6 envs: 10 whole rows of the newest 60 transitions, oldest first.
    testing.train_small("sb3_sac", tmp_path / "run", 3, SMALL, num_envs=6,
                        checkpoint=checkpoints.LATEST)
    assert loaded["pos"] == 10 and not loaded["full"]
    np.testing.assert_array_equal(loaded["rewards"][:10].flatten(), saved.flatten()[4:])


def test_a_replay_buffer_of_other_observations_is_one_line(tmp_path):
    checkpoint = _trained(tmp_path)
    env = testing.make_env()
    observations = env.single_observation_space
    env.close()
    buffer = ReplayBuffer(32, type(observations)(-np.inf, np.inf, (3,)),
                          type(observations)(-1, 1, (1,)), n_envs=4)
    with pytest.raises(LabError, match="does not fit this run: its 'observations' are of size"):
        offpolicy.load_memory(buffer, memory_path(checkpoint))


def lab(*args: str, logs: Path):
    return CliRunner().invoke(app, list(args), env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "300"})


@pytest.mark.parametrize(("sets", "said"), [
    (["agent.ent_coef=often"], "ent_coef"),
    (["agent.buffer_size=2"], "agent.buffer_size=2 holds less than one step of 4 envs"),
    (["agent.batch_size=512"], "agent.batch_size=512 is more than agent.buffer_size=256"),
])
def test_a_bad_setting_is_one_line(sets, said, tmp_path):
    args = [arg for value in [*SMALL, *sets] for arg in ("--set", value)]
    result = lab("train", "--task", "cartpole", "--framework", "sb3_sac", "--num-envs", "4",
                 *args, logs=tmp_path / "logs")
    assert_one_line_error(result, said)


def test_the_last_good_state_is_kept_without_the_buffer_and_resumes_with_an_empty_one(
        tmp_path, monkeypatch):
    # The state kept after every iteration between checkpoints holds the model only: the
    # buffer, rewritten whole at every save, would make each iteration slower as it fills.
    original, calls = offpolicy.OffPolicy.train, 0

    def poisoned(self, *args, **kwargs):  # the third update leaves NaN in the policy
        nonlocal calls
        calls += 1
        original(self, *args, **kwargs)
        if calls == 3:
            with torch.no_grad():
                for parameter in self.policy.parameters():
                    parameter.fill_(float("nan"))

    monkeypatch.setattr(offpolicy.OffPolicy, "train", poisoned)
    with pytest.raises(TrainingDiverged):
        testing.train_small("sb3_sac", tmp_path / "run", 10, [*SMALL, "agent.save_interval=10"])
    monkeypatch.undo()
    (run_dir,) = {p.parent for p in (tmp_path / "run").glob("*/cartpole/*/run.json")}
    good = registry.get_framework("sb3_sac").checkpoints(run_dir)[-1]
    assert good.iteration == 2 and not memory_path(good.path).exists()
    loaded = buffer_loads(monkeypatch)
    outcome = testing.train_small("sb3_sac", tmp_path / "run", 4, SMALL, checkpoint=good.path)
    assert (loaded["pos"], loaded["full"]) == (0, False)
    assert outcome.summary["iterations"] == 4


def test_a_checkpoint_loads_with_plain_sb3(tmp_path):
    checkpoint = _trained(tmp_path)
    env = testing.make_env()
    policy = testing.load_policy("sb3_sac", checkpoint, env)
    model = SAC.load(checkpoint, env=Sb3VecEnv(env), device="cpu")
    obs = torch.randn(8, env.single_observation_space.shape[0])
    actions, _ = model.predict(obs.numpy(), deterministic=True)
    with torch.no_grad():
        np.testing.assert_allclose(policy.actor(obs).numpy(), actions, atol=1e-6)
    env.close()
