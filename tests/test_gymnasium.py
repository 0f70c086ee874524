"""lab's env as gymnasium's clients use it: registered ids, `labcli.gym.make_env`, gymnasium's
own vector wrappers stacked as a user would, NEXT_STEP autoreset, and the VectorEnv contract
(seed lists, `closed`, `np_random`, pickling)."""

from __future__ import annotations

import copy
import pickle

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers import vector as wrappers

import labcli.gym
from labcli.envs import metrics
from labcli.envs.env import EPISODE, LabVecEnv
from labcli.errors import LabError
from labcli.plugins import registry

# gymnasium warns of its own unbounded observation Boxes and of float64 bounds it casts.
pytestmark = pytest.mark.filterwarnings("ignore:.*(infinity|precision lowered).*:UserWarning")

# Short episodes, so that a few steps end some.
SHORT = {"episode_length_s": 0.1}  # 5 env steps of 0.02 s


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo may write MUJOCO_LOG.TXT


def test_every_lab_task_is_a_gymnasium_id():
    assert labcli.gym.register() == [f"lab/{name}" for name in registry.loaded().names("task")]
    envs = gym.make_vec("lab/cartpole", num_envs=6, seed=2)
    try:
        assert isinstance(envs, LabVecEnv) and envs.num_envs == 6
        assert envs.spec.id == "lab/cartpole" and envs.spec.kwargs["num_envs"] == 6
        obs, _ = envs.reset()
        assert obs.shape == (6, 4) and obs.dtype == torch.float32
    finally:
        envs.close()


def test_module_syntax_registers_on_the_way():
    envs = gym.make_vec("labcli.gym:lab/cartpole", num_envs=2)
    envs.close()


def test_make_env_takes_config_fields_overrides_and_seed():
    envs = labcli.gym.make_env("cartpole", 3, seed=5, cart_bound=2.0,
                               overrides=["env.episode_length_s=2", "action_scale=20"])
    try:
        assert (envs.num_envs, envs.cfg.cart_bound, envs.cfg.episode_length_s,
                envs.cfg.action_scale) == (3, 2.0, 2.0, 20.0)
        again = labcli.gym.make_env("cartpole", 3, seed=5)
        assert torch.equal(envs.reset()[0], again.reset()[0])
        again.close()
    finally:
        envs.close()


@pytest.mark.parametrize(("kwargs", "named"), [
    ({"cart_bnd": 2.0}, "did you mean 'env.cart_bound'"),
    ({"overrides": ["env.cart_bound=far"]}, "env.cart_bound"),
    ({"autoreset_mode": "disabled"}, "autoreset_mode 'disabled'"),
    ({"backend": "tpu"}, "tpu"),
])
def test_make_env_refuses_bad_input_naming_it(kwargs, named):
    with pytest.raises(LabError) as err:
        labcli.gym.make_env("cartpole", 2, **kwargs)
    assert named in str(err.value)


def test_one_env_passes_gymnasium_s_env_checker():
    env = gym.make("lab/cartpole", **SHORT)
    try:
        check_env(env.unwrapped, skip_render_check=True)
        obs, _ = env.reset(seed=0)
        assert obs.dtype == np.float32 and env.observation_space.contains(obs)
        for _ in range(5):
            obs, reward, terminated, truncated, info = env.step(np.zeros(1, np.float32))
            assert isinstance(reward, float) and not terminated
        assert truncated and info[EPISODE]["l"] == 5 and "success" in info
        obs, _ = env.reset()  # the next episode starts where the user asks for it
        assert env.observation_space.contains(obs)
    finally:
        env.close()


def test_gymnasium_s_wrappers_stack_on_lab_s_env():
    """The wrappers CleanRL's PPO puts on its envs, vectorized: NumPy through ArrayConversion,
    statistics, action rescaling and clipping, observation and reward normalization."""
    envs = gym.make_vec("lab/cartpole", num_envs=8, autoreset_mode="next_step", **SHORT)
    envs = wrappers.ArrayConversion(envs, env_xp=torch, target_xp=np)
    envs = stats = wrappers.RecordEpisodeStatistics(envs)
    envs = wrappers.RescaleAction(envs, -2.0, 2.0)
    envs = wrappers.ClipAction(envs)
    envs = wrappers.NormalizeObservation(envs)
    envs = wrappers.TransformObservation(envs, lambda o: np.clip(o, -10, 10))
    envs = wrappers.NormalizeReward(envs, gamma=0.99)
    envs = wrappers.TransformReward(envs, lambda r: np.clip(r, -10, 10))
    try:
        obs, _ = envs.reset(seed=0)
        assert isinstance(obs, np.ndarray) and obs.shape == (8, 4)
        ended = None
        for _ in range(12):
            obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
            assert isinstance(reward, np.ndarray) and np.isfinite(obs).all()
            if "episode" in info:
                ended = info
        # gymnasium's statistics and lab's own, side by side under their own keys, agree.
        done = ended["_episode"]
        assert done.all() and (ended[f"_{EPISODE}"] == done).all()
        assert ended["episode"]["l"].tolist() == ended[EPISODE]["l"].tolist() == [5] * 8
        np.testing.assert_allclose(ended["episode"]["r"], ended[EPISODE]["r"], rtol=1e-5)
        assert list(stats.length_queue) == [5] * 16  # two episodes of each env
    finally:
        envs.close()


def test_next_step_autoreset_resets_on_the_step_after_and_ignores_its_action():
    same = labcli.gym.make_env("cartpole", 4, seed=1, **SHORT)
    nxt = labcli.gym.make_env("cartpole", 4, seed=1, autoreset_mode="next_step", **SHORT)
    try:
        assert nxt.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
        assert same.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
        torch.testing.assert_close(same.reset()[0], nxt.reset()[0])
        for _ in range(5):
            s = same.step(torch.zeros(4, 1))
            n = nxt.step(torch.zeros(4, 1))
        # The ending step: NEXT_STEP returns the last observation where SAME_STEP has reset.
        assert s[3].all() and n[3].all() and "final_obs" not in n[4]
        torch.testing.assert_close(n[0], s[4]["final_obs"])
        torch.testing.assert_close(n[1], s[1])
        assert n[4][EPISODE]["l"].tolist() == s[4][EPISODE]["l"].tolist() == [5] * 4
        # The step after: a reset to the task's start ranges, whatever the action; no reward,
        # nothing ends, and no non-finite action is counted.
        obs, reward, terminated, truncated, info = nxt.step(torch.full((4, 1), float("nan")))
        cfg = nxt.cfg
        for column, (low, high) in enumerate((cfg.reset_cart_pos, cfg.reset_pole_angle,
                                              cfg.reset_cart_vel, cfg.reset_pole_vel)):
            assert ((obs[:, column] >= low) & (obs[:, column] <= high)).all()
        assert (reward == 0).all() and not (terminated | truncated).any()
        assert not info[f"_{EPISODE}"].any()
        stats = nxt.pop_stats()
        assert stats[metrics.EPISODES] == 4 and stats[metrics.NONFINITE_ACTIONS] == 0
        # The next episode has its full 5 steps.
        for step in range(5):
            terminated, truncated = nxt.step(torch.zeros(4, 1))[2:4]
            assert (terminated | truncated).all() == (step == 4)
    finally:
        same.close()
        nxt.close()


def test_a_list_of_seeds_seeds_the_resets_and_np_random():
    envs = labcli.gym.make_env("cartpole", 3)
    try:
        first = envs.reset(seed=[1, 2, 3])[0]
        draw = envs.np_random.random()
        assert torch.equal(envs.reset(seed=[1, 2, 3])[0], first)
        assert envs.np_random.random() == draw
        assert not torch.equal(envs.reset(seed=[1, 2, 4])[0], first)
        envs.reset(seed=7)
        assert envs.np_random_seed == 7
        with pytest.raises(LabError, match="a list of 3 non-negative ints"):
            envs.reset(seed=[1, 2])
    finally:
        envs.close()


def test_closing_sets_closed_and_twice_is_harmless():
    envs = labcli.gym.make_env("cartpole", 2)
    assert not envs.closed
    envs.close()
    envs.close()
    assert envs.closed


@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
@pytest.mark.parametrize("mode", ["same_step", "next_step"])
def test_a_pickled_or_copied_env_steps_on_exactly_as_the_original(how, mode):
    envs = labcli.gym.make_env("cartpole", 4, seed=3, autoreset_mode=mode, **SHORT)
    gen = torch.Generator().manual_seed(0)
    actions = [torch.rand(4, 1, generator=gen) * 2 - 1 for _ in range(12)]
    envs.reset()
    for a in actions[:3]:
        envs.step(a)
    twin = pickle.loads(pickle.dumps(envs)) if how == "pickle" else copy.deepcopy(envs)
    try:
        assert twin.autoreset_mode is envs.autoreset_mode
        for a in actions[3:]:  # across episode ends (every 5 steps) and the resets they draw
            got, want = twin.step(a), envs.step(a)
            for g, w in zip(got[:4], want[:4], strict=True):
                assert torch.equal(g, w)
        assert twin.pop_stats() == envs.pop_stats()
        assert twin.np_random.random() == envs.np_random.random()
    finally:
        twin.close()
        envs.close()


# Bad input: a ValueError or TypeError naming the argument, as gymnasium's own envs raise --------
def _one_line(err: pytest.ExceptionInfo, *phrases: str) -> None:
    message = str(err.value)
    assert isinstance(err.value, LabError) and "\n" not in message, message
    for phrase in phrases:
        assert phrase in message, (phrase, message)


@pytest.mark.parametrize(("make", "kwargs", "error", "phrases"), [
    ("make_vec", {"seed": -1}, ValueError, ["seed must be a non-negative int, got -1"]),
    ("make_vec", {"seed": "x"}, TypeError, ["seed must be a non-negative int, got 'x' (str)"]),
    ("make_vec", {"seed": 1.5}, TypeError, ["got 1.5 (float)"]),
    ("make", {"seed": -1}, ValueError, ["seed must be a non-negative int, got -1"]),
    ("make", {"num_envs": 8}, TypeError,
     ["gym.make('lab/cartpole') makes one env, which takes no num_envs",
      "gym.make_vec('lab/cartpole', num_envs=8)"]),
    ("make", {"autoreset_mode": "same_step"}, TypeError, ["takes no autoreset_mode"]),
    ("make_vec", {"autoreset_mode": "disabled"}, ValueError,
     ["autoreset_mode 'disabled' is not one lab's env has", "'same_step', 'next_step'"]),
    ("make_vec", {"autoreset_mode": AutoresetMode.DISABLED}, ValueError,
     ["AutoresetMode.SAME_STEP"]),
    ("make_vec", {"autoreset_mode": 3}, TypeError, ["autoreset_mode must be an AutoresetMode or a "
                                                     "string, got 3 (int)"]),
    ("make_vec", {"overrides": "env.cart_bound=2"}, TypeError,
     ["overrides must be a list of 'KEY=VALUE' strings"]),
])
def test_bad_arguments_of_gym_make_are_value_or_type_errors_naming_them(make, kwargs, error,
                                                                        phrases):
    with pytest.raises(error) as err:
        envs = getattr(gym, make)("lab/cartpole", **kwargs)
        envs.close()
    _one_line(err, *phrases)


@pytest.mark.parametrize("mode", ["same_step", "SameStep", "SAME_STEP", AutoresetMode.SAME_STEP,
                                  "next_step", "NextStep", AutoresetMode.NEXT_STEP])
def test_autoreset_mode_is_gymnasium_s_enum_its_value_or_its_name(mode):
    envs = gym.make_vec("lab/cartpole", num_envs=2, autoreset_mode=mode)
    try:
        want = AutoresetMode.NEXT_STEP if "next" in str(mode).lower() else AutoresetMode.SAME_STEP
        assert envs.metadata["autoreset_mode"] is envs.autoreset_mode is want
    finally:
        envs.close()


@pytest.mark.parametrize(("kwargs", "error", "phrases"), [
    ({"seed": -1}, ValueError, ["reset(seed=...) must be None, a non-negative int or a list of 4 "
                                "non-negative ints (one per env), got -1"]),
    ({"seed": "x"}, TypeError, ["got 'x'"]),
    ({"seed": 1.5}, TypeError, ["got 1.5"]),
    ({"seed": [1, 2, 3]}, ValueError, ["a list of 4 non-negative ints", "got [1, 2, 3]"]),
    ({"seed": [1, 2, 3, "x"]}, TypeError, ["a list of 4 non-negative ints"]),
    ({"options": {"reset_mask": [True]}}, ValueError,
     ["options['reset_mask'] must be 4 bools, one per env", "got shape (1,)"]),
    ({"options": {"reset_mask": np.ones((1, 4), bool)}}, ValueError, ["got shape (1, 4)"]),
    ({"options": {"reset_mask": [1, 0, 1, 0]}}, TypeError, ["got dtype int64"]),
    ({"options": {"reset_mask": torch.zeros(4)}}, TypeError, ["got dtype torch.float32"]),
    ({"options": {"reset_mask": "abcd"}}, TypeError, ["got str"]),
    ({"options": {"reset_mask": True}}, TypeError, ["got bool"]),
    ({"options": "reset_mask"}, TypeError, ["reset(options=...) must be a dict or None, got str"]),
    ({"seed": 5, "options": {"reset_mask": [True]}}, ValueError, ["reset_mask"]),
])
def test_bad_reset_seeds_and_masks_are_value_or_type_errors_that_change_nothing(kwargs, error,
                                                                               phrases):
    envs = gym.make_vec("lab/cartpole", num_envs=4, seed=1)
    try:
        obs, _ = envs.reset(seed=3)
        envs.step(torch.full((4, 1), 0.5))
        before = envs.get_state()
        with pytest.raises(error) as err:
            envs.reset(**kwargs)
        _one_line(err, *phrases)
        after = envs.get_state()
        assert all(torch.equal(before[k], after[k]) for k in before) and envs.np_random_seed == 3
    finally:
        envs.close()


@pytest.mark.parametrize("mask", [np.array([True, False, True, False]),
                                  torch.tensor([True, False, True, False]),
                                  [True, False, True, False]])
def test_a_reset_mask_is_a_numpy_array_a_tensor_or_a_list_of_bools(mask):
    envs = gym.make_vec("lab/cartpole", num_envs=4, seed=1)
    try:
        envs.reset()
        envs.step(torch.ones(4, 1))
        length = envs.episode_length.clone()
        envs.reset(options={"reset_mask": mask})
        assert envs.episode_length.tolist() == [0, length[1], 0, length[3]]
    finally:
        envs.close()


@pytest.mark.parametrize("make", ["make_vec", "make"])
def test_a_closed_env_says_so_on_step_reset_and_render(make):
    env = getattr(gym, make)("lab/cartpole", **({"num_envs": 2} if make == "make_vec"
                                                else {"render_mode": "rgb_array"}))
    env.reset()
    env.close()
    action = torch.zeros(2, 1) if make == "make_vec" else np.zeros(1, np.float32)
    for call in (lambda: env.step(action), env.reset, env.unwrapped.render):
        with pytest.raises(ValueError) as err:
            call()
        assert isinstance(err.value, gym.error.ClosedEnvironmentError)
        _one_line(err, "after close(): this env of task 'cartpole' is closed")


def test_a_sharded_env_checks_seeds_and_masks_as_one_env_and_refuses_calls_once_closed():
    sharded = labcli.gym.make_env("cartpole", 128, threads=2)
    whole = labcli.gym.make_env("cartpole", 128, threads=1)
    try:
        assert type(sharded).__name__ == "ShardedVecEnv" and isinstance(whole, LabVecEnv)
        seeds = list(range(128))
        assert torch.equal(sharded.reset(seed=seeds)[0], whole.reset(seed=seeds)[0])
        with pytest.raises(ValueError) as err:
            sharded.reset(seed=seeds[:64])
        _one_line(err, "a list of 128 non-negative ints")
        # A bad mask is refused before any shard is asked: the workers stay in step.
        for mask, error in (([True], ValueError), (np.zeros(128, np.int64), TypeError)):
            with pytest.raises(error) as err:
                sharded.reset(options={"reset_mask": mask})
            _one_line(err, "options['reset_mask'] must be 128 bools")
        mask = np.zeros(128, bool)
        mask[:3] = True
        assert torch.equal(sharded.reset(options={"reset_mask": mask})[0],
                           whole.reset(options={"reset_mask": mask})[0])
        assert torch.equal(sharded.step(torch.zeros(128, 1))[0], whole.step(torch.zeros(128, 1))[0])
    finally:
        sharded.close()
        whole.close()
    for call in (lambda: sharded.step(torch.zeros(128, 1)), sharded.reset):
        with pytest.raises(ValueError) as err:
            call()
        _one_line(err, "after close(): this env of task 'cartpole' is closed")
