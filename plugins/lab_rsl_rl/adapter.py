"""lab's torch VectorEnv seen through RSL-RL's VecEnv API.

RSL-RL wants observations as a TensorDict of named groups, one done flag per env, and time-outs
in `extras["time_outs"]` so that PPO bootstraps the value of an episode cut by the time limit
instead of treating it as terminal. Both sides speak torch on the same device: no copies.
"""

from __future__ import annotations

from typing import Any

import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

# The observation group the actor reads, and the critic where the task gives no critic group of
# its own (RSL-RL's `obs_groups` name them).
OBS_GROUP, CRITIC_GROUP = "policy", "critic"


class RslRlVecEnv(VecEnv):
    def __init__(self, env: Any):
        base = env.unwrapped  # env-stage wrappers in front of a LabVecEnv keep its attributes
        self.env = env
        self.num_envs = env.num_envs
        self.num_actions = env.single_action_space.shape[0]
        self.device = base.device
        self.max_episode_length = base.max_episode_length
        # The runner writes this only for `init_at_random_ep_len`, which lab does not use.
        self.episode_length_buf = base.episode_length
        self.cfg = base.cfg
        self._obs, info = env.reset()
        self._critic = info.get("critic_obs")  # a task's critic observations, where it has them

    def get_observations(self) -> TensorDict:
        groups = {OBS_GROUP: self._obs}
        if self._critic is not None:
            groups[CRITIC_GROUP] = self._critic
        return TensorDict(groups, batch_size=[self.num_envs], device=self.device)

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        self._obs, reward, terminated, truncated, info = self.env.step(actions)
        self._critic = info.get("critic_obs")
        # Same-step autoreset: `_obs` already holds the first observation of the next episode.
        extras = {"time_outs": truncated}
        return self.get_observations(), reward, terminated | truncated, extras

    def close(self) -> None:
        self.env.close()
