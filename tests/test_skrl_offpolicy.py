"""skrl's SAC and TD3 in lab: what the conformance suite does not reach (the squashed actor's
probabilities, a replay memory that wraps around or meets another env count, TD3's update
count)."""

from __future__ import annotations

import io
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from lab_skrl import offpolicy
from lab_skrl.offpolicy import memory_path
from lab_skrl.sac import SquashedActor
from rich.console import Console
from skrl.memories.torch import RandomMemory
from torch.distributions import Normal, TransformedDistribution
from torch.distributions.transforms import AffineTransform, TanhTransform

from labcli import testing
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.runs import checkpoints

SMALL = testing.SMALL_AGENTS["skrl_sac"]


def test_the_squashed_actor_s_log_probability_is_that_of_tanh_of_a_gaussian():
    torch.manual_seed(0)
    observations = gym.spaces.Box(-np.inf, np.inf, (5,))
    actions = gym.spaces.Box(-100, 100, (3,))
    actor = SquashedActor(observations, actions, "cpu", [16], "relu", bound=2.0)
    obs = torch.randn(64, 5)
    sampled, outputs = actor.act({"observations": obs})
    mean, log_std = actor.net(obs).chunk(2, dim=-1)
    squashed = TransformedDistribution(Normal(mean, log_std.clamp(-5, 2).exp()),
                                       [TanhTransform(cache_size=1), AffineTransform(0, 2.0)])
    expected = squashed.log_prob(sampled).sum(-1, keepdim=True)
    # lab leaves out the constant log(bound) a dimension: it moves no gradient.
    assert torch.allclose(outputs["log_prob"] - 3 * np.log(2.0), expected, atol=1e-4)
    assert sampled.abs().max() <= 2.0
    assert torch.equal(actor.compute({"observations": obs})[0], torch.tanh(mean) * 2.0)
    uniform = actor.random_act({"observations": torch.zeros(4096, 5)})[0]
    assert uniform.abs().max() <= 2.0 and uniform.abs().max() > 1.9


@pytest.mark.parametrize("name", ["skrl_sac", "skrl_td3"])
def test_a_resume_after_the_replay_memory_wrapped_around_equals_an_unbroken_run(name, tmp_path):
    # 4 envs × 8 steps an iteration into 48 transitions: full after 1.5 iterations. TD3
    # updates its actor every third critic update, so a resume must go on counting them.
    overrides = [*testing.SMALL_AGENTS[name], "agent.buffer_size=48"]
    if name == "skrl_td3":
        overrides.append("agent.policy_delay=3")
    assert testing.check_resume(name, tmp_path, overrides) == 0.0


def memory_loads(monkeypatch) -> dict:
    """What the next resume's replay memory holds once loaded: where it writes next, whether it
    is full, its rewards."""
    loaded = {}
    original = offpolicy.load_memory

    def load(memory, checkpoint):
        original(memory, checkpoint)
        loaded.update(index=memory.memory_index, filled=memory.filled,
                      rewards=memory.tensors["rewards"].clone())

    monkeypatch.setattr(offpolicy, "load_memory", load)
    return loaded


def _trained(tmp_path) -> Path:
    """The checkpoint of 2 iterations of SAC in tmp_path/run."""
    outcome = testing.train_small("skrl_sac", tmp_path / "run", 2, SMALL)
    return registry.get_framework("skrl_sac").checkpoint_path(outcome.run.dir, 2)


def test_a_checkpoint_saves_the_replay_memory_beside_it(tmp_path):
    checkpoint = _trained(tmp_path)
    saved = torch.load(memory_path(checkpoint), weights_only=True)
    # 2 iterations × 8 steps of 4 envs: 16 rows of 4 transitions, written on from row 16.
    assert saved["memory_index"] == 16 and not saved["filled"]
    assert saved["tensors"]["observations"].shape[:2] == (16, 4)
    assert memory_path(checkpoint).name == "memory_2.pt"


def test_only_the_newest_checkpoint_keeps_the_replay_memory_and_an_older_one_resumes_empty(
        tmp_path, monkeypatch):
    # A memory of a million transitions is hundreds of MB: one beside every checkpoint took
    # gigabytes within minutes.
    spec = registry.get_framework("skrl_sac")
    outcome = testing.train_small("skrl_sac", tmp_path / "run", 3,
                                  [*SMALL, "agent.save_interval=1"])
    run_dir = outcome.run.dir
    found = spec.checkpoints(run_dir)
    assert [c.iteration for c in found] == [1, 2, 3]
    assert [memory_path(c.path).exists() for c in found] == [False, False, True]
    assert all(checkpoints.complete(spec, c) for c in found)
    assert "memory_1.pt" not in (run_dir / "checkpoint_1.json").read_text()
    loaded = memory_loads(monkeypatch)
    said = io.StringIO()
    resumed = testing.train_small("skrl_sac", tmp_path / "run", 4, SMALL, checkpoint=found[0].path,
                                  console=Console(file=said, width=300))
    assert (loaded["index"], loaded["filled"]) == (0, False)
    assert ("note: model_1.pt holds no replay memory (only a run's newest checkpoint keeps it); "
            "the resumed run starts with an empty one") in said.getvalue()
    assert resumed.summary["iterations"] == 4
    # The resumed run's checkpoint 4 is the newest now: 3's memory went.
    assert [memory_path(c.path).exists() for c in spec.checkpoints(run_dir)] == [False] * 3 + [True]


def test_a_checkpoint_without_its_replay_memory_is_not_resumed(tmp_path):
    checkpoint = _trained(tmp_path)
    memory_path(checkpoint).unlink()
    with pytest.raises(LabError, match="no complete checkpoint of a skrl_sac run"):
        testing.train_small("skrl_sac", tmp_path / "run", 3, SMALL, checkpoint=checkpoints.LATEST)


def test_a_resume_with_another_env_count_keeps_the_newest_transitions(tmp_path, monkeypatch):
    loaded = memory_loads(monkeypatch)
    checkpoint = _trained(tmp_path)  # 16 rows of 4 envs: 64 transitions
    saved = torch.load(memory_path(checkpoint), weights_only=True)["tensors"]["rewards"]
    # 6 envs: 10 whole rows of the newest 60 transitions, oldest first.
    testing.train_small("skrl_sac", tmp_path / "run", 3, SMALL, num_envs=6,
                        checkpoint=checkpoints.LATEST)
    assert loaded["index"] == 10 and not loaded["filled"]
    assert torch.equal(loaded["rewards"][:10].flatten(), saved.flatten()[4:])


def test_a_replay_memory_of_other_observations_is_one_line(tmp_path):
    checkpoint = _trained(tmp_path)
    # A memory of 3 observations where the run's have 4.
    memory = RandomMemory(memory_size=8, num_envs=4, device="cpu")
    for name, size in (("observations", 3), ("next_observations", 3), ("actions", 1),
                       ("rewards", 1), ("terminated", 1)):
        memory.create_tensor(name=name, size=size,
                             dtype=torch.bool if name == "terminated" else torch.float32)
    with pytest.raises(LabError, match="does not fit this run: its 'observations' are of size"):
        offpolicy.load_memory(memory, checkpoint)


def test_a_buffer_smaller_than_one_step_of_the_envs_is_refused(tmp_path):
    with pytest.raises(LabError, match="agent.buffer_size=2 holds less than one step of 4 envs"):
        testing.train_small("skrl_sac", tmp_path, 1, [*SMALL, "agent.buffer_size=2"])


def test_the_last_good_state_is_kept_without_the_memory_and_resumes_with_an_empty_one(
        tmp_path, monkeypatch):
    # The state kept after every iteration between checkpoints holds the agent only: the
    # memory, rewritten whole at every save, would make each iteration slower as it fills.
    from test_unstable import poison_update

    from labcli.errors import TrainingDiverged

    poison_update(monkeypatch, "skrl_sac", on_call=3)
    with pytest.raises(TrainingDiverged):
        testing.train_small("skrl_sac", tmp_path / "run", 10, [*SMALL, "agent.save_interval=10"])
    monkeypatch.undo()
    (run_dir,) = {p.parent for p in (tmp_path / "run").glob("*/cartpole/*/run.json")}
    good = registry.get_framework("skrl_sac").checkpoints(run_dir)[-1]
    assert good.iteration == 2 and not memory_path(good.path).exists()
    loaded = memory_loads(monkeypatch)
    outcome = testing.train_small("skrl_sac", tmp_path / "run", 4, SMALL, checkpoint=good.path)
    assert (loaded["index"], loaded["filled"]) == (0, False)
    assert outcome.summary["iterations"] == 4
