"""`stagger_episodes`: a fresh training run starts each env's first episode at a random step
before the time-out, as Isaac Lab's and mjlab's rsl_rl training do (`init_at_random_ep_len`);
play and a resumed run's saved episodes never are."""

from __future__ import annotations

import pytest
import torch

from labcli import testing
from labcli.envs.env import LabVecEnv
from labcli.envs.shards import ShardedVecEnv
from labcli.plugins import registry
from labcli.runs import checkpoints

STEPS = 20  # the time-out, in env steps
# Cartpole's pole upright and at rest: with no push no episode ends before its time-out.
AT_REST = {"reset_cart_pos": (0.0, 0.0), "reset_pole_angle": (0.0, 0.0),
           "reset_cart_vel": (0.0, 0.0), "reset_pole_vel": (0.0, 0.0)}


def staggered_start(env, seed: int) -> torch.Tensor:
    env.start_staggered()
    env.reset(seed=seed)
    return env.episode_length.clone()


def test_each_env_s_first_episode_starts_at_a_random_step_and_ends_that_much_sooner():
    env = testing.make_env(64, episode_length_s=STEPS * 0.02, **AT_REST)  # 0.02 s a step
    twin = testing.make_env(64, episode_length_s=STEPS * 0.02, **AT_REST)
    try:
        start = staggered_start(env, seed=1)
        assert env.max_episode_length == STEPS
        assert start.min() >= 0 and start.max() < STEPS and len(start.unique()) > STEPS // 2
        assert torch.equal(staggered_start(twin, seed=1), start)  # the env's seed draws them
        assert not torch.equal(staggered_start(twin, seed=2), start)
        ended_after = torch.zeros(64, dtype=torch.long)
        for step in range(1, STEPS + 1):
            _, _, terminated, truncated, _ = env.step(torch.zeros(64, 1))
            assert not terminated.any()
            ended_after[truncated & (ended_after == 0)] = step
        assert torch.equal(ended_after, STEPS - start)
        env.reset()  # once only: the next full reset starts every episode at its first step
        assert (env.episode_length == 0).all()
    finally:
        env.close()
        twin.close()


def test_every_shard_staggers_its_envs_as_one_env_would():
    spec = registry.get_task(testing.TASK)
    sharded = ShardedVecEnv(spec, spec.config_class(num_envs=128), seed=0, shards=2)
    one = testing.make_env(128)
    try:
        assert torch.equal(staggered_start(sharded, seed=3), staggered_start(one, seed=3))
    finally:
        sharded.close()
        one.close()


@pytest.fixture
def staggering(monkeypatch) -> list[int]:
    """How many times training asked an env to stagger its next reset (the real method runs)."""
    calls: list[int] = []
    original = LabVecEnv.start_staggered

    def counted(self):
        calls.append(self.num_envs)
        original(self)

    monkeypatch.setattr(LabVecEnv, "start_staggered", counted)
    return calls


def test_a_fresh_run_staggers_a_resumed_one_goes_on_with_its_saved_episodes(tmp_path,
                                                                           staggering):
    sets = [*testing.SMALL_AGENTS["rsl_rl"], "env.stagger_episodes=true"]
    testing.train_small("rsl_rl", tmp_path, 1, sets)
    assert staggering == [testing.NUM_ENVS]
    testing.train_small("rsl_rl", tmp_path, 2, sets, checkpoint=checkpoints.LATEST)
    assert staggering == [testing.NUM_ENVS]
    testing.train_small("rsl_rl", tmp_path, 1, testing.SMALL_AGENTS["rsl_rl"])
    assert staggering == [testing.NUM_ENVS]  # off by default


def test_a_staggered_run_resumes_as_it_would_have_gone_on(tmp_path):
    sets = [*testing.SMALL_AGENTS["rsl_rl"], "env.stagger_episodes=true"]
    assert testing.check_resume("rsl_rl", tmp_path, sets) == 0.0


@pytest.mark.parametrize("task, staggered", [("panda-lift", True), ("yam-lift", True),
                                             ("panda-reach", False), (testing.TASK, False)])
def test_the_lift_tasks_stagger_by_default_where_episodes_end_together(task, staggered):
    # A lift's episodes seldom end before the time-out; a reach's, measured, gained nothing.
    assert registry.get_task(task).config_class().stagger_episodes is staggered
