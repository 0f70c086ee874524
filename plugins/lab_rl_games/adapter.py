"""lab's torch VectorEnv seen through rl_games' `IVecEnv`.

rl_games takes torch tensors as they are (on the env's device) and folds terminations and
time-outs into one `dones`; it bootstraps the value on the time-outs it finds in
`infos["time_outs"]` (its `value_bootstrap`), as Isaac Lab's rl_games wrapper provides them.
"""

from __future__ import annotations

from typing import Any

import torch
from rl_games.common.ivecenv import IVecEnv


class RlGamesVecEnv(IVecEnv):
    def __init__(self, env: Any):
        self.env = env

    @property
    def num_envs(self) -> int:
        return self.env.num_envs

    def step(self, actions: torch.Tensor):
        obs, reward, terminated, truncated, _ = self.env.step(actions)
        # rl_games keeps `dones` as bytes in its buffers.
        dones = (terminated | truncated).to(torch.uint8)
        return obs, reward, dones, {"time_outs": truncated}

    def reset(self) -> torch.Tensor:
        obs, _ = self.env.reset()
        return obs

    def get_number_of_agents(self) -> int:
        return 1

    def get_env_info(self) -> dict[str, Any]:
        return {"observation_space": self.env.single_observation_space,
                "action_space": self.env.single_action_space, "agents": 1, "value_size": 1}

    def close(self) -> None:
        self.env.close()
