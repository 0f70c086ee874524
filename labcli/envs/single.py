"""One env of a lab task as a plain `gymnasium.Env`, NumPy in and out: what `gym.make("lab/<task>")`
returns, for gymnasium's single-env tools (its env checker, its wrappers, `play`)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch

from labcli.envs.env import EPISODE, LabVecEnv


class SingleEnv(gym.Env):
    """Steps a `LabVecEnv` of one env with NEXT_STEP autoreset: an ended episode's step returns
    its last observation, and the caller's `reset()` starts the next, as a gymnasium Env does.
    `info` holds `success` (and lab's episode figures) on the step that ends an episode."""

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(self, env: LabVecEnv, render_mode: str | None = None):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode {render_mode!r}: lab's envs render 'rgb_array'")
        self.env = env
        self.render_mode = render_mode
        self.observation_space = env.single_observation_space
        self.action_space = env.single_action_space
        self.metadata = {**self.metadata, "render_fps": round(1.0 / env.step_dt)}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        obs, _ = self.env.reset(seed=seed)
        return obs[0].cpu().numpy(), {}

    def step(self, action: Any):
        actions = torch.as_tensor(np.asarray(action, dtype=np.float32)).reshape(1, -1)
        obs, reward, terminated, truncated, info = self.env.step(actions)
        out: dict[str, Any] = {}
        if bool(info[f"_{EPISODE}"][0]):
            episode = {key: value[0].item() for key, value in info[EPISODE].items()}
            out = {"success": episode["success"], EPISODE: episode}
        return (obs[0].cpu().numpy(), float(reward[0]), bool(terminated[0]),
                bool(truncated[0]), out)

    def render(self) -> np.ndarray | None:
        return self.env.render() if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        self.env.close()
        super().close()
