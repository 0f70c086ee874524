"""The adapter: lab's env (a gymnasium VectorEnv of torch tensors) as the library's env."""

from __future__ import annotations

from typing import Any

import torch


class PPOEnv:
    def __init__(self, env: Any):
        self.env = env
        self.num_envs = env.num_envs
        self.observation_size = env.single_observation_space.shape[0]
        self.action_size = env.single_action_space.shape[0]

    def reset(self) -> torch.Tensor:
        obs, _ = self.env.reset()
        return obs

    def step(self, actions: torch.Tensor) -> tuple[torch.Tensor, ...]:
        # lab's env resets ended envs within the step: `obs` is already the next episode's.
        obs, reward, terminated, truncated, _ = self.env.step(actions)
        return obs, reward, (terminated | truncated).float(), truncated.float()

    def close(self) -> None:
        self.env.close()
