"""lab's torch VectorEnv seen through skrl's env wrapper API.

skrl's agents take torch tensors already, so the adapter only reshapes: rewards and done flags
become `[num_envs, 1]`, and the spaces are the single-env ones skrl sizes its models and memory
from. Time-outs stay in `truncated`, apart from `terminated`, so that PPO bootstraps values on
them; `info["final_obs"]` keeps each ended env's true last observation for that bootstrap. A
task's critic observations are skrl's states (`state_space`, `state()`), for PPO's value model.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from skrl.envs.wrappers.torch.base import Wrapper


class SkrlEnv(Wrapper):
    def __init__(self, env: Any):
        super().__init__(env)
        self._states: torch.Tensor | None = None  # the last reset's or step's critic_obs

    @property
    def observation_space(self) -> gym.Space:
        return self._env.single_observation_space

    @property
    def action_space(self) -> gym.Space:
        return self._env.single_action_space

    @property
    def state_space(self) -> gym.Space | None:
        size = self._env.unwrapped.critic_observation_size
        return gym.spaces.Box(-np.inf, np.inf, (size,), np.float32) if size else None

    @property
    def num_envs(self) -> int:
        return self._env.num_envs

    def reset(self) -> tuple[torch.Tensor, dict[str, Any]]:
        obs, info = self._env.reset()
        self._states = info.get("critic_obs")
        return obs, info

    def step(self, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor,
                                                   torch.Tensor, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self._env.step(actions)
        self._states = info.get("critic_obs")
        return obs, reward.view(-1, 1), terminated.view(-1, 1), truncated.view(-1, 1), info

    def state(self) -> torch.Tensor | None:
        return self._states

    def render(self, *args: Any, **kwargs: Any) -> None:
        return None  # lab records video with an env-stage wrapper, not through skrl

    def close(self) -> None:
        self._env.close()
