"""LabVecEnv on the cpu backend with the cartpole task: the gymnasium VectorEnv contract, episode
bookkeeping, time-outs against terminations, decimation, seeding, partial resets, robustness to
bad actions and diverged physics, and the batched stepping through mujoco.rollout."""

from __future__ import annotations

import gc
import math
import threading
from collections.abc import Callable, Iterator

import gymnasium as gym
import mujoco
import numpy as np
import pytest
import torch
from gymnasium.vector import AutoresetMode
from lab_cartpole.config import CartpoleConfig
from mujoco import rollout

from labcli.envs import metrics
from labcli.envs.env import UNSTABLE, LabVecEnv
from labcli.errors import LabError
from labcli.plugins import registry

NUM_ENVS = 8
OBS, ACT = 4, 1
DT = 0.01  # cartpole.xml's timestep
STEP_DT = DT * 2  # at the default decimation
CART, POLE = 0, 1  # qpos / qvel columns
# Cartpole's reward terms and causes, as its config and task name them.
TERMS = ["alive", "terminating", "pole_angle", "cart_vel", "pole_vel"]
OUT_OF_BOUNDS = "cart_out_of_bounds"
# Pole upright, everything at rest: with no push it stays exactly there, so the outcome of an
# episode is known in advance.
AT_REST = {"reset_cart_pos": (0.0, 0.0), "reset_pole_angle": (0.0, 0.0),
           "reset_cart_vel": (0.0, 0.0), "reset_pole_vel": (0.0, 0.0)}


@pytest.fixture
def make_env(tmp_path, monkeypatch) -> Iterator[Callable[..., LabVecEnv]]:
    """Builds cartpole envs on the cpu backend and closes their thread pools after the test."""
    # MuJoCo appends its warnings (the unstable-state tests cause some) to ./MUJOCO_LOG.TXT.
    monkeypatch.chdir(tmp_path)
    made: list[LabVecEnv] = []

    def make(num_envs: int = NUM_ENVS, seed: int = 0, **overrides) -> LabVecEnv:
        spec = registry.get_task("cartpole")
        env = LabVecEnv(spec, spec.config_class(num_envs=num_envs, **overrides), backend="cpu",
                        seed=seed)
        made.append(env)
        return env

    yield make
    for env in made:
        env.close()


def zeros(n: int = NUM_ENVS) -> torch.Tensor:
    return torch.zeros(n, ACT)


def random_actions(steps: int, n: int = NUM_ENVS, seed: int = 0) -> torch.Tensor:
    """Actions beyond [-1, 1] included, so that clipping is part of every trajectory."""
    return torch.randn(steps, n, ACT, generator=torch.Generator().manual_seed(seed)) * 1.5


def rollout_of(env: LabVecEnv, actions: torch.Tensor, seed: int | None = None) -> dict:
    obs, _ = env.reset(seed=seed)
    out = {"obs": [obs], "reward": [], "terminated": [], "truncated": [], "final_obs": []}
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        for key, value in (("obs", obs), ("reward", reward), ("terminated", terminated),
                           ("truncated", truncated), ("final_obs", info["final_obs"])):
            out[key].append(value.clone())
    return {key: torch.stack(values) for key, values in out.items()}


# The VectorEnv contract ------------------------------------------------------------------------
def test_is_a_gymnasium_vector_env_with_same_step_autoreset(make_env):
    env = make_env()
    assert isinstance(env, gym.vector.VectorEnv)
    assert env.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    assert env.num_envs == NUM_ENVS and env.backend == "cpu" and env.device == torch.device("cpu")
    assert env.single_observation_space.shape == (OBS,)
    assert env.single_action_space == gym.spaces.Box(-1.0, 1.0, (ACT,), np.float32)
    assert env.observation_space.shape == (NUM_ENVS, OBS)
    assert env.action_space.shape == (NUM_ENVS, ACT)
    assert env.observation_names == ["cart_pos", "pole_angle", "cart_vel", "pole_vel"]
    assert env.action_names == ["cart_force"]


def test_reset_and_step_return_batched_torch_tensors(make_env):
    env = make_env()
    obs, info = env.reset(seed=0)
    assert isinstance(obs, torch.Tensor) and obs.dtype == torch.float32
    assert obs.shape == (NUM_ENVS, OBS) and isinstance(info, dict)
    # Gymnasium's own sampler gives numpy; the env takes it as well as torch.
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    for value, dtype, shape in ((obs, torch.float32, (NUM_ENVS, OBS)),
                                (reward, torch.float32, (NUM_ENVS,)),
                                (terminated, torch.bool, (NUM_ENVS,)),
                                (truncated, torch.bool, (NUM_ENVS,)),
                                (info["final_obs"], torch.float32, (NUM_ENVS, OBS)),
                                (info["_final_obs"], torch.bool, (NUM_ENVS,)),
                                (info["_lab_episode"], torch.bool, (NUM_ENVS,)),
                                (info["lab_episode"]["r"], torch.float32, (NUM_ENVS,)),
                                (info["lab_episode"]["l"], torch.long, (NUM_ENVS,)),
                                (info["lab_episode"]["success"], torch.bool, (NUM_ENVS,)),
                                (info["terminations"], torch.bool, (NUM_ENVS, 2))):
        assert isinstance(value, torch.Tensor) and value.dtype == dtype and value.shape == shape
    assert torch.isfinite(obs).all() and torch.isfinite(reward).all()


def test_same_step_autoreset_keeps_the_true_last_observation(make_env):
    short = make_env(seed=5, episode_length_s=5 * STEP_DT)
    # Same seed and actions, no time-out: its 5th observation is what `short` saw last.
    long = make_env(seed=5)
    short.reset()
    long.reset()
    for step in range(5):
        obs, _, _, truncated, info = short.step(zeros())
        long_obs, *_ = long.step(zeros())
        if step < 4:
            assert not truncated.any() and not info["_final_obs"].any()
            torch.testing.assert_close(obs, long_obs, rtol=0, atol=0)
    assert truncated.all() and info["_final_obs"].all()
    torch.testing.assert_close(info["final_obs"], long_obs, rtol=0, atol=0)
    assert (obs != info["final_obs"]).any(dim=1).all()
    # The returned observation is a fresh start from the reset ranges (qpos = obs[:, :2]).
    low, high = CartpoleConfig().reset_cart_pos
    assert ((obs[:, 0] >= low) & (obs[:, 0] <= high)).all()
    assert (obs[:, 1].abs() <= 0.25 * math.pi + 1e-6).all()
    assert (obs[:, 2:].abs() <= 0.5 + 1e-6).all()


def test_episode_info_has_the_returns_and_lengths_of_ended_episodes(make_env):
    env = make_env(episode_length_s=5 * STEP_DT)
    env.reset(seed=1)
    actions = random_actions(10)
    returns = torch.zeros(NUM_ENVS)
    for step, action in enumerate(actions):
        _, reward, terminated, truncated, info = env.step(action)
        returns += reward
        done = terminated | truncated
        assert torch.equal(info["_lab_episode"], done)
        if step in (4, 9):
            assert done.all()
            torch.testing.assert_close(info["lab_episode"]["r"], returns)
            assert (info["lab_episode"]["l"] == 5).all()
            # The second episode's return starts from zero, not from the first one's.
            returns.zero_()
        else:
            assert not done.any()
            assert (info["lab_episode"]["l"] == step % 5 + 1).all()


# Episode statistics ----------------------------------------------------------------------------
def test_pop_stats_logs_each_reward_term_and_the_means_of_ended_episodes(make_env):
    env = make_env(episode_length_s=5 * STEP_DT)
    env.reset(seed=2)
    assert env.pop_stats() == {}  # no episode ended yet
    returns = torch.zeros(NUM_ENVS)
    for action in random_actions(5):
        _, reward, *_ = env.step(action)
        returns += reward
    stats = env.pop_stats()
    assert stats[metrics.EPISODES] == NUM_ENVS
    assert stats[metrics.MEAN_LENGTH] == 5
    assert stats[metrics.MEAN_RETURN] == pytest.approx(returns.mean().item(), rel=1e-5)
    per_term = {k.removeprefix(metrics.REWARD_TERM): v for k, v in stats.items()
                if k.startswith(metrics.REWARD_TERM)}
    assert sorted(per_term) == sorted(TERMS)
    # Weighted sums: "alive" earns its weight every step, and the terms add up to the return.
    assert per_term["alive"] == pytest.approx(5 * CartpoleConfig().reward_weights["alive"])
    assert sum(per_term.values()) == pytest.approx(stats[metrics.MEAN_RETURN], rel=1e-5)
    assert stats[metrics.TERMINATION + OUT_OF_BOUNDS] == 0
    assert stats[metrics.TERMINATION + UNSTABLE] == 0 and stats[metrics.INSTABILITIES] == 0
    assert env.pop_stats() == {}  # read once, then cleared


@pytest.mark.parametrize(("pole_angle", "expected"), [(0.0, 1.0), (0.5, 0.0)])
def test_success_rate_is_judged_on_the_final_state(make_env, pole_angle, expected):
    env = make_env(episode_length_s=3 * STEP_DT,
                   **{**AT_REST, "reset_pole_angle": (pole_angle, pole_angle)})
    env.reset()
    for _ in range(3):
        *_, info = env.step(zeros())
    assert info["lab_episode"]["success"].tolist() == [bool(expected)] * NUM_ENVS
    assert env.pop_stats()[metrics.SUCCESS_RATE] == expected


def test_time_outs_are_truncations_not_terminations(make_env):
    env = make_env(episode_length_s=5 * STEP_DT)
    env.reset(seed=3)
    for step in range(5):
        _, _, terminated, truncated, info = env.step(zeros())
        assert not terminated.any() and not info["terminations"].any()
        assert truncated.all() == (step == 4) and truncated.any() == (step == 4)
    stats = env.pop_stats()
    assert stats[metrics.EPISODES] == NUM_ENVS
    assert stats[metrics.TERMINATION + OUT_OF_BOUNDS] == 0


def test_leaving_the_rail_is_a_termination_not_a_time_out(make_env):
    env = make_env(cart_bound=0.1, **{**AT_REST, "reset_cart_pos": (0.5, 0.5)})
    env.reset()
    _, reward, terminated, truncated, info = env.step(zeros())
    assert terminated.all() and not truncated.any()
    causes = env.termination_names
    assert causes == [OUT_OF_BOUNDS, UNSTABLE]
    assert info["terminations"][:, causes.index(OUT_OF_BOUNDS)].all()
    assert not info["terminations"][:, causes.index(UNSTABLE)].any()
    weights = CartpoleConfig().reward_weights
    # alive + terminating (pole upright, at rest: the angle and velocity terms are ~0).
    expected = weights["alive"] + weights["terminating"]
    torch.testing.assert_close(reward, torch.full((NUM_ENVS,), expected), atol=1e-3, rtol=0)
    assert not info["lab_episode"]["success"].any()  # a terminated episode never succeeds
    stats = env.pop_stats()
    assert stats[metrics.TERMINATION + OUT_OF_BOUNDS] == 1.0
    assert stats[metrics.MEAN_LENGTH] == 1


def test_a_termination_on_the_time_out_step_is_a_termination(make_env):
    env = make_env(episode_length_s=STEP_DT, cart_bound=0.1,
                   **{**AT_REST, "reset_cart_pos": (0.5, 0.5)})
    env.reset()
    _, _, terminated, truncated, _ = env.step(zeros())
    # Terminal, so that no learner bootstraps a value from a state the task calls final.
    assert terminated.all() and not truncated.any()


@pytest.mark.parametrize(("episode_length_s", "steps"), [
    (0.1, 5),
    (0.3, 15),
    (0.14, 7),  # 0.14 / 0.02 is 7.000000000000001 in floating point
])
def test_time_out_after_episode_length_over_step_dt(make_env, episode_length_s, steps):
    env = make_env(num_envs=2, episode_length_s=episode_length_s, **AT_REST)
    env.reset()
    taken = 0
    truncated = torch.zeros(2, dtype=torch.bool)
    while not truncated.all() and taken <= steps:
        _, _, _, truncated, _ = env.step(zeros(2))
        taken += 1
    assert taken == steps


# Physics: decimation and the batched cpu backend -----------------------------------------------
def reference_step(model: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray, ctrl: np.ndarray,
                   nstep: int) -> tuple[np.ndarray, np.ndarray]:
    """One env at a time through plain mujoco.mj_step: what the batched backend must equal."""
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
    for _ in range(nstep):
        mujoco.mj_step(model, data)
    return data.qpos.copy(), data.qvel.copy()


@pytest.mark.parametrize("decimation", [1, 3])
def test_one_env_step_is_decimation_physics_steps_of_every_env(make_env, decimation):
    env = make_env(decimation=decimation)
    assert env.step_dt == pytest.approx(DT * decimation)
    env.reset(seed=4)
    scale = env.cfg.action_scale
    for action in random_actions(3):
        qpos, qvel = env.sim.qpos.numpy().copy(), env.sim.qvel.numpy().copy()
        env.step(action)
        ctrl = env.sim.ctrl.numpy()
        np.testing.assert_array_equal(ctrl, (action.clamp(-1, 1) * scale).double().numpy())
        for i in range(NUM_ENVS):
            want_qpos, want_qvel = reference_step(env.sim.model, qpos[i], qvel[i], ctrl[i],
                                                  decimation)
            np.testing.assert_allclose(env.sim.qpos[i].numpy(), want_qpos, rtol=0, atol=1e-12)
            np.testing.assert_allclose(env.sim.qvel[i].numpy(), want_qvel, rtol=0, atol=1e-12)


def test_decimation_holds_the_action_over_its_physics_steps(make_env):
    coarse = make_env(decimation=4, **AT_REST)
    fine = make_env(decimation=1, **AT_REST)
    coarse.reset()
    fine.reset()
    push = torch.full((NUM_ENVS, ACT), 0.3)
    coarse.step(push)
    for _ in range(4):
        fine.step(push)
    torch.testing.assert_close(coarse.sim.qpos, fine.sim.qpos, rtol=0, atol=1e-12)
    torch.testing.assert_close(coarse.sim.qvel, fine.sim.qvel, rtol=0, atol=1e-12)
    assert coarse.sim.qpos[:, CART].gt(0).all()  # it moved, so the comparison means something


def test_sim_dt_overrides_the_models_timestep(make_env):
    env = make_env(sim_dt=0.005, decimation=3)
    assert env.sim.model.opt.timestep == 0.005
    assert env.step_dt == pytest.approx(0.015)


def test_cpu_backend_steps_every_env_once_per_step_in_rollout_calls(make_env, monkeypatch):
    env = make_env(threads=2)
    env.reset(seed=0)
    calls: list[int] = []
    original = rollout.Rollout.rollout

    def counted(self, model, *args, **kwargs):
        calls.append(len(model))
        return original(self, model, *args, **kwargs)

    def no_python_stepping(*args, **kwargs):
        raise AssertionError("the cpu backend stepped an env from Python")

    monkeypatch.setattr(rollout.Rollout, "rollout", counted)
    monkeypatch.setattr(mujoco, "mj_step", no_python_stepping)
    for action in random_actions(3):
        env.step(action)
        # One call on the calling thread, one on the worker thread: every env exactly once.
        assert len(calls) == 2 and sum(calls) == NUM_ENVS and min(calls) > 0
        calls.clear()


@pytest.mark.parametrize("threads", [2, 3, 16])
def test_the_thread_count_does_not_change_a_trajectory(make_env, threads):
    # Short episodes: resets are part of it. 16 threads for 8 envs: one env per thread at most.
    actions = random_actions(40)
    one = rollout_of(make_env(seed=3, threads=1, episode_length_s=6 * STEP_DT), actions)
    many_env = make_env(seed=3, threads=threads, episode_length_s=6 * STEP_DT)
    many = rollout_of(many_env, actions)
    for key in one:
        torch.testing.assert_close(many[key], one[key], rtol=0, atol=0)
    assert many_env.sim.nthread == min(threads, NUM_ENVS)


def test_an_error_on_the_physics_thread_reaches_the_caller(make_env, monkeypatch):
    env = make_env(threads=2)
    env.reset(seed=0)
    theirs = env.sim._theirs
    monkeypatch.setattr(theirs, "rollout", lambda *a, **k: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        env.step(zeros())
    monkeypatch.undo()  # the thread survived its job's error and steps again
    before = env.sim.qpos.clone()
    env.step(torch.ones(NUM_ENVS, ACT))
    assert env.sim.qpos[:, CART].gt(before[:, CART]).all()


def physics_threads() -> int:
    return sum(t.name == "lab-physics" for t in threading.enumerate())


def test_the_physics_thread_ends_with_its_env(make_env):
    before = physics_threads()
    env = make_env(threads=2)
    env.step(zeros())
    assert physics_threads() == before + 1
    env.close()
    env.close()  # twice is harmless
    assert physics_threads() == before
    with pytest.raises(ValueError, match=r"step\(\) after close\(\)"):  # not a hang
        env.step(zeros())
    # An env never closed lets its thread go when it is collected.
    spec = registry.get_task("cartpole")
    unclosed = LabVecEnv(spec, spec.config_class(num_envs=4, threads=2), backend="cpu")
    unclosed.step(torch.zeros(4, ACT))
    assert physics_threads() == before + 1
    del unclosed
    gc.collect()
    assert physics_threads() == before


# Seeding and resets ----------------------------------------------------------------------------
def test_same_seed_same_trajectory_other_seed_another(make_env):
    # Short episodes, so that autoresets (and their random draws) are part of the trajectory.
    actions = random_actions(12)
    a = rollout_of(make_env(seed=7, episode_length_s=4 * STEP_DT), actions)
    b = rollout_of(make_env(seed=7, episode_length_s=4 * STEP_DT), actions)
    c = rollout_of(make_env(seed=8, episode_length_s=4 * STEP_DT), actions)
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=0, atol=0)
    assert a["truncated"].any()
    assert not torch.allclose(a["obs"][0], c["obs"][0])
    assert not torch.allclose(a["obs"][-1], c["obs"][-1])


def test_reset_with_a_seed_reseeds(make_env):
    env = make_env(seed=0)
    first, _ = env.reset(seed=11)
    env.step(random_actions(1)[0])
    again, _ = env.reset(seed=11)
    other, _ = env.reset(seed=12)
    torch.testing.assert_close(first, again, rtol=0, atol=0)
    assert not torch.allclose(first, other)


def test_only_ended_envs_are_reset(make_env):
    env = make_env(seed=9)
    twin = make_env(seed=9)  # same draws, nothing pushed off the rail
    env.reset()
    twin.reset()
    ended = torch.zeros(NUM_ENVS, dtype=torch.bool)
    ended[[1, 4]] = True
    for _ in range(3):
        env.step(zeros())
        twin.step(zeros())
    env.sim.qpos[ended, CART] = 3.2  # the state views are live: this is where the next step starts
    obs, _, terminated, _, info = env.step(zeros())
    twin_obs, *_ = twin.step(zeros())
    assert torch.equal(terminated, ended)
    assert info["lab_episode"]["l"][ended].tolist() == [4, 4]
    torch.testing.assert_close(obs[~ended], twin_obs[~ended], rtol=0, atol=0)
    assert not torch.allclose(obs[ended], twin_obs[ended])
    # Lengths: the untouched envs go on counting, the reset ones start again.
    _, _, _, _, info = env.step(zeros())
    assert info["lab_episode"]["l"].tolist() == [1 if e else 5 for e in ended.tolist()]


def test_task_and_sim_reset_touch_only_the_masked_envs(make_env):
    env = make_env(seed=10)
    env.reset()
    for action in random_actions(3):
        env.step(action)
    qpos, qvel = env.sim.qpos.clone(), env.sim.qvel.clone()
    mask = torch.tensor([True, False] * (NUM_ENVS // 2))
    env.sim.reset_to_defaults(mask)
    assert (env.sim.qpos[mask] == 0).all() and (env.sim.qvel[mask] == 0).all()
    env.task.reset(mask, env.rng)
    assert torch.equal(env.sim.qpos[~mask], qpos[~mask])
    assert torch.equal(env.sim.qvel[~mask], qvel[~mask])
    assert (env.sim.qpos[mask] != qpos[mask]).all() and (env.sim.qpos[mask] != 0).all()


def test_reset_mask_option_resets_only_those_envs(make_env):
    env = make_env(seed=12)
    env.reset()
    for action in random_actions(3):
        env.step(action)
    before = env.sim.qpos.clone()
    mask = np.array([True, False] * (NUM_ENVS // 2))
    env.reset(options={"reset_mask": mask})
    assert torch.equal(env.sim.qpos[~torch.from_numpy(mask)], before[~torch.from_numpy(mask)])


# Bad actions and diverged physics --------------------------------------------------------------
def test_actions_are_clipped_to_the_action_space(make_env):
    clipped = make_env(seed=13)
    wild = make_env(seed=13)
    clipped.reset()
    wild.reset()
    inside = torch.tensor([1.0, -1.0, 0.5, -0.25, 1.0, -1.0, 0.0, 1.0])[:, None]
    outside = torch.tensor([7.5, -3.0, 0.5, -0.25, 1e6, -1e6, 0.0, 1.0000001])[:, None]
    obs, *_ = clipped.step(inside)
    wild_obs, *_ = wild.step(outside)
    torch.testing.assert_close(wild_obs, obs, rtol=0, atol=0)
    torch.testing.assert_close(wild.sim.ctrl, inside.double() * wild.cfg.action_scale)


def test_clip_actions_sets_the_bound_and_the_action_space(make_env):
    env = make_env(clip_actions=2.5, action_scale=3.0)
    env.reset()
    assert (env.single_action_space.low.tolist(), env.single_action_space.high.tolist()) == (
        [-2.5], [2.5])
    assert env.describe()["action_range"] == [-2.5, 2.5]
    env.step(torch.tensor([7.5, -3.0, 2.0, -0.25, 1e6, -1e6, 0.0, 2.5000001])[:, None])
    expected = torch.tensor([2.5, -2.5, 2.0, -0.25, 2.5, -2.5, 0.0, 2.5], dtype=torch.float64)
    torch.testing.assert_close(env.sim.ctrl, expected[:, None] * 3.0)


def test_non_finite_actions_reset_the_env_and_count_as_unstable(make_env):
    env = make_env(seed=14)
    env.reset()
    actions = random_actions(1)[0].clamp(-1, 1)
    bad = torch.zeros(NUM_ENVS, dtype=torch.bool)
    bad[:3] = True
    actions[:3, 0] = torch.tensor([float("nan"), float("inf"), -float("inf")])
    obs, reward, terminated, truncated, info = env.step(actions)
    assert torch.isfinite(obs).all() and torch.isfinite(info["final_obs"]).all()
    assert torch.isfinite(reward).all() and (reward[bad] == 0).all()
    assert torch.equal(terminated, bad) and not truncated.any()
    assert torch.equal(info["terminations"][:, env.termination_names.index(UNSTABLE)], bad)
    assert (info["lab_episode"]["l"][bad] == 1).all()
    stats = env.pop_stats()
    assert stats[metrics.INSTABILITIES] == 3 and stats[metrics.TERMINATION + UNSTABLE] == 1.0
    # The reset envs go on normally.
    obs, _, terminated, *_ = env.step(zeros())
    assert torch.isfinite(obs).all() and not terminated.any()


def assert_only_env_0_unstable(env: LabVecEnv, obs, reward, terminated, info) -> None:
    assert torch.isfinite(obs).all() and obs.abs().max() < 10  # env 0 starts afresh
    assert terminated.tolist() == [True] + [False] * (NUM_ENVS - 1)
    unstable = info["terminations"][:, env.termination_names.index(UNSTABLE)]
    assert unstable.tolist() == [True] + [False] * (NUM_ENVS - 1)
    assert reward[0] == 0  # a diverged state earns nothing
    assert env.pop_stats()[metrics.INSTABILITIES] == 1


def test_a_runaway_velocity_counts_as_unstable(make_env):
    env = make_env(seed=15)
    env.reset()
    env.sim.qvel[0, CART] = 2e6  # beyond the env's 1e6 limit, within MuJoCo's own 1e10
    obs, reward, terminated, _, info = env.step(zeros())
    assert_only_env_0_unstable(env, obs, reward, terminated, info)


def test_a_task_s_lower_speed_limit_counts_a_runaway_as_unstable(make_env):
    """`unstable_velocity`: a pole spun to 200 rad/s diverged at a limit of 100, not at the
    default 1e6."""
    strict, loose = make_env(seed=15, unstable_velocity=100.0), make_env(seed=15)
    for env in (strict, loose):
        env.reset()
        env.sim.qvel[0, POLE] = 200.0
    obs, reward, terminated, _, info = strict.step(zeros())
    assert_only_env_0_unstable(strict, obs, reward, terminated, info)
    _, _, _, _, info = loose.step(zeros())
    assert not info["terminations"][:, loose.termination_names.index(UNSTABLE)].any()


@pytest.mark.parametrize("pole_vel", [float("nan"), 1e7])
def test_a_state_mujoco_rejects_counts_as_unstable(make_env, pole_vel):
    env = make_env(seed=16)
    env.reset()
    env.sim.qvel[0, POLE] = pole_vel  # NaN, or a qacc beyond MuJoCo's 1e10
    obs, reward, terminated, _, info = env.step(zeros())
    assert_only_env_0_unstable(env, obs, reward, terminated, info)


@pytest.mark.parametrize("mode", ["same_step", "next_step"])
def test_the_cpus_shortcuts_change_no_output(tmp_path, monkeypatch, mode):
    """On the CPU a step skips masking and episode figures where no env ended, diverged or got
    a non-finite action: the same run with all of it done on every step, as on a GPU, gives the
    same outputs and figures, bit for bit."""
    monkeypatch.chdir(tmp_path)  # MuJoCo's warnings file
    spec = registry.get_task("cartpole")
    envs = [LabVecEnv(spec, spec.config_class(num_envs=64), backend="cpu", seed=3,
                      autoreset_mode=mode) for _ in range(2)]
    fast, full = envs
    full._shortcuts = False
    try:
        for env in envs:
            env.reset(seed=3)
        for step, actions in enumerate(random_actions(300, n=64, seed=4)):
            if step == 50:
                actions[5, 0] = float("nan")
            if step == 120:  # finite, but their sum is not: none of them is bad
                actions.fill_(3e38)
            if step == 80:
                for env in envs:
                    env.sim.qvel[7, CART] = 2e6
            outs = [env.step(actions.clone()) for env in envs]
            for a, b in zip(*outs, strict=True):
                if isinstance(a, dict):
                    assert a.keys() == b.keys()
                    a, b = (torch.cat([v.reshape(64, -1).double() for v in (
                        *x.pop("lab_episode").values(), *x.values())], 1) for x in (a, b))
                assert torch.equal(a, b), f"step {step}"
            if step == 120:
                assert not outs[0][4]["terminations"][:, -1].any()
            if step % 50 == 49:
                assert fast.pop_stats() == full.pop_stats()
        assert fast.pop_stats() == full.pop_stats()
    finally:
        for env in envs:
            env.close()


# Configuration errors --------------------------------------------------------------------------
@pytest.mark.parametrize("weights", [
    {t: 1.0 for t in TERMS if t != "pole_vel"},  # a computed term left unweighted
    {**{t: 1.0 for t in TERMS}, "energy": 1.0},  # a weight for a term the task never computes
])
def test_reward_weights_must_match_the_reward_terms(weights):
    spec = registry.get_task("cartpole")
    with pytest.raises(LabError) as err:
        LabVecEnv(spec, spec.config_class(num_envs=2, reward_weights=weights), backend="cpu")
    message = str(err.value)
    assert "cartpole" in message and "pole_vel" in message
    assert ("energy" in message) == ("energy" in weights)
    assert "one entry per reward term" in err.value.hint
