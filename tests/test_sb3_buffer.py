"""lab's SB3 PPO (lab_sb3.ppo) against SB3's own: the device rollout buffer gives SB3's returns,
advantages and mini-batches, and a whole training run with it ends with SB3's parameters and
episode figures. Run on the CPU here (the buffer is device-agnostic torch); on a GPU it is what
`lab train --framework sb3` uses."""

from __future__ import annotations

import json
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch
from lab_sb3.adapter import Sb3VecEnv
from lab_sb3.ppo import DeviceRolloutBuffer, LabPPO
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer

from labcli import testing

STEPS, ENVS, OBS, ACTIONS = 6, 5, 3, 2
DEVICES = ["cpu", pytest.param("cuda", marks=[pytest.mark.gpu, pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs a CUDA GPU")])]
OBS_SPACE = gym.spaces.Box(-np.inf, np.inf, (OBS,), dtype=np.float32)
ACTION_SPACE = gym.spaces.Box(-1.0, 1.0, (ACTIONS,), dtype=np.float32)


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
    assert "rollout_buffer_class" not in data and "rollout_buffer_kwargs" not in data
    loaded = PPO.load(tmp_path / "model.zip", device="cpu")
    assert type(loaded.rollout_buffer) is RolloutBuffer
    obs = np.zeros((1, 4), dtype=np.float32)
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0],
                               model.predict(obs, deterministic=True)[0])


@pytest.mark.parametrize("dones", [None, np.array([False, True, False])])
def test_lab_ppo_reads_the_ended_envs_infos(dones):
    model = LabPPO("MlpPolicy", Sb3VecEnv(testing.make_env(num_envs=3)), device="cpu",
                   n_steps=8, batch_size=8)
    model._setup_learn(8)  # makes the episode buffers
    episode = {"r": 1.0, "l": 5}
    model._update_info_buffer([{}, {"episode": episode, "is_success": True}, {}], dones)
    assert list(model.ep_info_buffer) == [episode]
    assert list(model.ep_success_buffer) == ([] if dones is None else [True])
