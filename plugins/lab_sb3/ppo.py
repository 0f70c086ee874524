"""SB3's PPO with less host work per step, through SB3's own extension points: its
`rollout_buffer_class`, a subclass and a VecEnv wrapper. The updates are SB3's.

With thousands of envs, SB3's host-side NumPy work dominates an iteration on a GPU (humanoid,
4,096 envs, one H100: of 1.17 s an iteration, 0.50 s in the update, 0.29 s of it SB3's buffer
indexing NumPy arrays and copying each mini-batch to the device; 0.45 s of the rollout outside
the env).
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.type_aliases import RolloutBufferSamples
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvWrapper
from torch.distributions import Distribution

from lab_sb3.algorithm import LabAlgorithm

# torch checks a distribution's parameters when it is made, which on a GPU waits for the device
# (SB3 makes one each rollout step and each mini-batch). skrl turns it off at import, RSL-RL
# when it makes its policy's distribution.
Distribution.set_default_validate_args(False)

# SB3's RolloutBuffer fields, [n_steps, n_envs, ...] each
FIELDS = ("observations", "actions", "rewards", "episode_starts", "values", "log_probs",
          "advantages", "returns")


class DeviceRolloutBuffer(RolloutBuffer):
    """SB3's RolloutBuffer with its arrays as tensors on the policy's device: values and
    log-probabilities stay there (SB3 reads both back to the host each step), returns and
    advantages are computed there, and a mini-batch is an index into them rather than a NumPy
    gather copied over. The same samples as SB3's buffer, in the same order: the shuffle is
    SB3's `np.random.permutation`."""

    def __init__(self, *args: Any, **kwargs: Any):
        self._tensors: dict[str, torch.Tensor] | None = None
        super().__init__(*args, **kwargs)  # which calls reset()

    def reset(self) -> None:
        if self._tensors is None:
            steps, envs = self.buffer_size, self.n_envs
            shapes = {"observations": self.obs_shape, "actions": (self.action_dim,)}
            self._tensors = {name: torch.zeros((steps, envs, *shapes.get(name, ())),
                                               dtype=torch.float32, device=self.device)
                             for name in FIELDS}
        self._flat: dict[str, torch.Tensor] | None = None  # the rollout as get() samples it
        self.pos, self.full = 0, False

    def add(self, obs: np.ndarray, action: np.ndarray, reward: np.ndarray,
            episode_start: np.ndarray, value: torch.Tensor, log_prob: torch.Tensor) -> None:
        t, pos = self._tensors, self.pos
        t["observations"][pos].copy_(torch.as_tensor(obs).reshape(t["observations"].shape[1:]))
        t["actions"][pos].copy_(torch.as_tensor(action).reshape(t["actions"].shape[1:]))
        t["rewards"][pos].copy_(torch.as_tensor(reward))
        t["episode_starts"][pos].copy_(torch.as_tensor(episode_start))
        t["values"][pos].copy_(value.reshape(-1))
        t["log_probs"][pos].copy_(log_prob.reshape(-1))
        self.pos += 1
        self.full = self.pos == self.buffer_size

    def compute_returns_and_advantage(self, last_values: torch.Tensor, dones: np.ndarray) -> None:
        """SB3's GAE(λ), the same recursion on the device."""
        t = self._tensors
        values, starts = t["values"], t["episode_starts"]
        next_values = last_values.detach().reshape(-1).to(values)
        next_live = 1.0 - torch.as_tensor(dones, dtype=torch.float32).to(values.device)
        last = torch.zeros_like(next_values)
        for step in reversed(range(self.buffer_size)):
            delta = t["rewards"][step] + self.gamma * next_values * next_live - values[step]
            last = delta + self.gamma * self.gae_lambda * next_live * last
            t["advantages"][step] = last
            next_values, next_live = values[step], 1.0 - starts[step]
        torch.add(t["advantages"], values, out=t["returns"])

    # PPO.train reads these two as NumPy arrays for its explained variance.
    @property
    def values(self) -> np.ndarray:
        return self._tensors["values"].cpu().numpy()

    @property
    def returns(self) -> np.ndarray:
        return self._tensors["returns"].cpu().numpy()

    def get(self, batch_size: int | None = None) -> Generator[RolloutBufferSamples, None, None]:
        assert self.full, ""
        total = self.buffer_size * self.n_envs
        order = torch.as_tensor(np.random.permutation(total), device=self.device)
        if self._flat is None:  # SB3's swap_and_flatten: [n_envs * n_steps, ...], env-major
            self._flat = {name: tensor.swapaxes(0, 1).reshape(total, *tensor.shape[2:])
                          for name, tensor in self._tensors.items()}
        size = total if batch_size is None else batch_size
        flat = self._flat
        for start in range(0, total, size):
            index = order[start:start + size]
            yield RolloutBufferSamples(*(flat[name][index] for name in (
                "observations", "actions", "values", "log_probs", "advantages", "returns")))


class TimeoutBootstrap(VecEnvWrapper):
    """SB3 adds to a timed-out env's reward the discounted value of its last observation, one
    env and one forward pass at a time, each read back to the host (at 4,096 humanoids with
    16 s episodes, ~4 a step). This adds them for all of a step's time-outs in one batch, then
    takes those envs' `TimeLimit.truncated` flag so that SB3's loop passes them by."""

    def __init__(self, venv: VecEnv, model: PPO):
        super().__init__(venv)
        self.model = model

    def reset(self) -> np.ndarray:
        return self.venv.reset()

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        timed_out = [i for i in np.flatnonzero(dones)
                     if infos[i].get("terminal_observation") is not None
                     and infos[i].get("TimeLimit.truncated", False)]
        if timed_out:
            policy = self.model.policy
            last = np.stack([infos[i]["terminal_observation"] for i in timed_out])
            with torch.no_grad():
                values = policy.predict_values(policy.obs_to_tensor(last)[0])
            rewards[timed_out] += self.model.gamma * values.reshape(-1).cpu().numpy()
            for i in timed_out:
                del infos[i]["TimeLimit.truncated"]
        return obs, rewards, dones, infos


class LabPPO(LabAlgorithm, PPO):
    """SB3's PPO (with lab_sb3.algorithm's changes), bootstrapping time-outs in one batch a
    step (`TimeoutBootstrap`)."""

    def collect_rollouts(self, env: VecEnv, *args: Any, **kwargs: Any) -> bool:
        return super().collect_rollouts(TimeoutBootstrap(env, self), *args, **kwargs)
