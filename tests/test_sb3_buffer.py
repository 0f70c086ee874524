"""lab's faster parts of SB3 against SB3's own: the device rollout buffer (lab_sb3.ppo) gives SB3's
returns, advantages and mini-batches, and a whole training run with it and the batched
time-out bootstrap ends with SB3's parameters and episode figures; the batched VecNormalize
gives VecNormalize's observations, rewards, last observations and statistics; a zip without the
last observations loads and trains on in plain SB3. Run on the CPU here (the buffer is
device-agnostic torch); on a GPU the buffer is what `lab train --framework sb3` uses."""

from __future__ import annotations

import importlib.util
import json
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch
from lab_sb3.adapter import BatchedVecNormalize, Sb3VecEnv
from lab_sb3.ppo import DeviceRolloutBuffer, LabPPO
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.vec_env import VecNormalize

from labcli import testing

STEPS, ENVS, OBS, ACTIONS = 6, 5, 3, 2
DEVICES = ["cpu", pytest.param("cuda", marks=[pytest.mark.gpu, pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs a CUDA GPU")])]
HAVE_WARP = all(importlib.util.find_spec(m) for m in ("warp", "mujoco_warp"))
OBS_SPACE = gym.spaces.Box(-np.inf, np.inf, (OBS,), dtype=np.float32)
ACTION_SPACE = gym.spaces.Box(-1.0, 1.0, (ACTIONS,), dtype=np.float32)


@pytest.fixture(autouse=True)
def sb3_logs(tmp_path, monkeypatch):
    """SB3 makes a log dir (/tmp/SB3-<time> by default) for each model that learns without a
    logger set: the tests' go under their own tmp_path."""
    monkeypatch.setenv("SB3_LOGDIR", str(tmp_path / "sb3"))


def filled(cls: type[RolloutBuffer], device: str) -> RolloutBuffer:
    """A buffer holding one seeded rollout with episode starts and ends in it."""
    rng = np.random.default_rng(0)
    buffer = cls(STEPS, OBS_SPACE, ACTION_SPACE, device=device, gae_lambda=0.9, gamma=0.95,
                 n_envs=ENVS)
    for _ in range(STEPS):
        buffer.add(rng.normal(size=(ENVS, OBS)).astype(np.float32),
                   rng.uniform(-1, 1, (ENVS, ACTIONS)).astype(np.float32),
                   rng.normal(size=ENVS).astype(np.float32), rng.random(ENVS) < 0.3,
                   torch.tensor(rng.normal(size=(ENVS, 1)), dtype=torch.float32, device=device),
                   torch.tensor(rng.normal(size=ENVS), dtype=torch.float32, device=device))
    buffer.compute_returns_and_advantage(
        torch.tensor(rng.normal(size=(ENVS, 1)), dtype=torch.float32, device=device),
        rng.random(ENVS) < 0.5)
    return buffer


@pytest.mark.parametrize("device", DEVICES)
def test_device_buffer_gives_sb3s_returns_advantages_and_mini_batches(device):
    ours, sb3 = filled(DeviceRolloutBuffer, device), filled(RolloutBuffer, device)
    assert ours.full and sb3.full
    np.testing.assert_allclose(ours.returns, sb3.returns, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(ours.values, sb3.values)
    for _epoch in range(2):  # the second epoch reads the flattened tensors again
        np.random.seed(7)
        mine = list(ours.get(batch_size=8))
        np.random.seed(7)
        theirs = list(sb3.get(batch_size=8))
        assert [len(b.observations) for b in mine] == [8, 8, 8, 6]
        for a, b in zip(mine, theirs, strict=True):
            for name, x, y in zip(a._fields, a, b, strict=True):
                torch.testing.assert_close(x, y, msg=name, rtol=1e-6, atol=1e-6)
    ours.reset()
    assert not ours.full and ours.pos == 0


def run(cls: type[PPO], buffer: type[RolloutBuffer] | None) -> PPO:
    env = Sb3VecEnv(testing.make_env(episode_length_s=0.1))  # 5-step episodes: some end
    model = cls("MlpPolicy", env, n_steps=8, batch_size=16, n_epochs=2, seed=3, device="cpu",
                policy_kwargs={"net_arch": [16, 16]}, rollout_buffer_class=buffer)
    model.learn(total_timesteps=3 * 8 * env.num_envs)
    return model


def test_lab_ppo_with_the_device_buffer_trains_as_sb3s_ppo():
    # 5-step episodes: time-outs in most steps, each bootstrapped by TimeoutBootstrap.
    ours, sb3 = run(LabPPO, DeviceRolloutBuffer), run(PPO, None)
    for (name, a), b in zip(ours.policy.state_dict().items(), sb3.policy.state_dict().values(),
                            strict=True):
        torch.testing.assert_close(a, b, msg=name, rtol=1e-5, atol=1e-6)
    assert len(sb3.ep_info_buffer) > 0
    assert list(ours.ep_info_buffer) == list(sb3.ep_info_buffer)
    assert list(ours.ep_success_buffer) == list(sb3.ep_success_buffer)


def test_lab_ppo_zip_loads_with_plain_sb3(tmp_path):
    model = run(LabPPO, DeviceRolloutBuffer)
    model.save(tmp_path / "model.zip")
    with zipfile.ZipFile(tmp_path / "model.zip") as archive:
        data = json.loads(archive.read("data"))
    assert not {"rollout_buffer_class", "rollout_buffer_kwargs", "_last_obs",
                "_last_episode_starts", "_last_original_obs"} & set(data)
    env = Sb3VecEnv(testing.make_env(episode_length_s=0.1))
    loaded = PPO.load(tmp_path / "model.zip", env=env, device="cpu")
    assert type(loaded.rollout_buffer) is RolloutBuffer
    obs = np.zeros((1, 4), dtype=np.float32)
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0],
                               model.predict(obs, deterministic=True)[0])
    loaded.learn(total_timesteps=8 * env.num_envs, reset_num_timesteps=False)  # SB3 resets
    assert loaded.num_timesteps == model.num_timesteps + 8 * env.num_envs


@pytest.mark.parametrize("dones", [None, np.array([False, True, False])])
def test_lab_ppo_reads_the_ended_envs_infos(dones):
    model = LabPPO("MlpPolicy", Sb3VecEnv(testing.make_env(num_envs=3)), device="cpu",
                   n_steps=8, batch_size=8)
    model._setup_learn(8)  # makes the episode buffers
    episode = {"r": 1.0, "l": 5}
    model._update_info_buffer([{}, {"episode": episode, "is_success": True}, {}], dones)
    assert list(model.ep_info_buffer) == [episode]
    assert list(model.ep_success_buffer) == ([] if dones is None else [True])


def test_batched_vec_normalize_gives_sb3s_vec_normalize():
    # A small clip_obs: some observations are clipped.
    ours, sb3 = (cls(Sb3VecEnv(testing.make_env(episode_length_s=0.1)), norm_reward=True,
                     clip_obs=1.0) for cls in (BatchedVecNormalize, VecNormalize))
    np.testing.assert_array_equal(ours.reset(), sb3.reset())
    rng = np.random.default_rng(0)
    ended, clipped, returned = 0, 0, []
    for _ in range(12):
        actions = rng.uniform(-1, 1, (ours.num_envs, 1)).astype(np.float32)
        a, b = ours.step(actions), sb3.step(actions)
        returned.append((a[0], a[0].copy()))  # what a step returned stays as it was
        clipped += int((np.abs(a[0]) == 1.0).sum())
        for x, y in zip(a[:3], b[:3], strict=True):
            np.testing.assert_array_equal(x, y)
        for x, y in zip(a[3], b[3], strict=True):
            assert x.keys() == y.keys()
            if "terminal_observation" in x:
                ended += 1
                assert x["terminal_observation"].dtype == np.float32
                np.testing.assert_array_equal(x["terminal_observation"],
                                              y["terminal_observation"])
    assert ended >= ours.num_envs  # every env ended at least once
    assert clipped > 0
    for obs, copy in returned:
        np.testing.assert_array_equal(obs, copy)
    np.testing.assert_array_equal(ours.obs_rms.var, sb3.obs_rms.var)
    np.testing.assert_array_equal(ours.ret_rms.var, sb3.ret_rms.var)
    np.testing.assert_array_equal(ours.get_original_obs(), sb3.get_original_obs())


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=[
    pytest.mark.gpu, pytest.mark.skipif(not (torch.cuda.is_available() and HAVE_WARP),
                                        reason="needs a CUDA GPU and MuJoCo Warp")])])
def test_batched_vec_normalize_on_the_device_gives_sb3s_vec_normalize(device, monkeypatch):
    """The GPU's path (on the CPU by forcing it): SB3's numbers but for the batch moments, which
    it sums in float64."""
    if device == "cpu":
        monkeypatch.setattr(BatchedVecNormalize, "on_device", property(lambda self: True))
    ours, sb3 = (cls(Sb3VecEnv(testing.make_env(16, device, episode_length_s=0.1)),
                     clip_obs=1.0) for cls in (BatchedVecNormalize, VecNormalize))
    assert ours.on_device
    close = {"rtol": 1e-5, "atol": 1e-5}
    np.testing.assert_allclose(ours.reset(), sb3.reset(), **close)
    rng = np.random.default_rng(0)
    clipped = 0
    for _ in range(12):
        actions = rng.uniform(-1, 1, (ours.num_envs, 1)).astype(np.float32)
        (obs, rewards, dones, infos), theirs = ours.step(actions), sb3.step(actions)
        assert obs.dtype == np.float32
        np.testing.assert_allclose(obs, theirs[0], **close)
        np.testing.assert_array_equal(rewards, theirs[1])
        np.testing.assert_array_equal(dones, theirs[2])
        np.testing.assert_array_equal(ours.get_original_obs(), sb3.get_original_obs())
        for x, y in zip(infos, theirs[3], strict=True):
            if "terminal_observation" in y:
                np.testing.assert_allclose(x["terminal_observation"], y["terminal_observation"],
                                           **close)
        clipped += int((np.abs(obs) == 1.0).sum())
    assert clipped > 0
    np.testing.assert_allclose(ours.obs_rms.mean, sb3.obs_rms.mean, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(ours.obs_rms.var, sb3.obs_rms.var, rtol=1e-6, atol=1e-7)
    assert ours.obs_rms.count == sb3.obs_rms.count
