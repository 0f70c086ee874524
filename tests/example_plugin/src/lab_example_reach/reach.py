"""The task: config, observations, reward terms, terminations, reset and success, all batched
torch over `[num_envs, ...]`, so that it runs unchanged on the cpu and warp backends."""

from __future__ import annotations

import torch
from pydantic import Field

from labcli.envs.config import TaskConfig
from labcli.envs.random import EnvRandom
from labcli.envs.sim import Sim
from labcli.envs.task import Task


class ReachConfig(TaskConfig):
    # Re-declaring a base field replaces its Field: repeat the constraint with the new default.
    episode_length_s: float = Field(4.0, gt=0, description="time-out, in seconds")
    decimation: int = Field(4, gt=0, description="physics steps per env step")
    action_scale: float = Field(2.0, gt=0, description="newtons per axis at action 1")
    reward_weights: dict[str, float] = Field(default_factory=lambda: {
        "near": 1.0, "at_target": 1.0, "effort": -0.05, "leaving": -10.0,
    })
    arena: float = Field(1.0, gt=0, description="half-width of the square arena, metres")
    start_range: float = Field(0.5, ge=0, description="start within ±this on each axis")
    target_range: float = Field(0.8, ge=0, description="targets within ±this on each axis")
    target_radius: float = Field(0.1, gt=0, description="closer than this is at the target")


class Reach(Task):
    cfg: ReachConfig
    observation_names = ["x", "y", "vx", "vy", "to_target_x", "to_target_y"]
    action_names = ["force_x", "force_y"]
    # What a deployment must feed and command (exported beside the policy).
    observation_units = {"x": "m", "y": "m", "vx": "m/s", "vy": "m/s",
                         "to_target_x": "m, target minus puck",
                         "to_target_y": "m, target minus puck"}
    action_units = {"force_x": "N", "force_y": "N"}

    def __init__(self, cfg: ReachConfig, sim: Sim):
        super().__init__(cfg, sim)
        # Per-env task state lives next to the sim's, on its device. The env asks for the reward
        # terms once before the first reset (to check their names), so it must exist already.
        self.target = torch.zeros_like(sim.qpos)

    def state(self) -> dict[str, torch.Tensor]:
        # Saved with the env's state and restored in place: a resumed run goes on exactly.
        return {"target": self.target}

    def _to_target(self) -> torch.Tensor:
        return self.target - self.sim.qpos

    def observations(self) -> torch.Tensor:
        return torch.cat((self.sim.qpos, self.sim.qvel, self._to_target()), dim=1)

    def _outside(self) -> torch.Tensor:
        return (self.sim.qpos.abs() > self.cfg.arena).any(dim=1)

    def reward_terms(self) -> dict[str, torch.Tensor]:
        distance = self._to_target().norm(dim=1)
        action = self.sim.ctrl / self.cfg.action_scale
        return {
            # In [0, 1]: with a penalty per step instead, leaving the arena at once would be
            # the best policy.
            "near": 1.0 - torch.tanh(distance / 0.5),
            "at_target": (distance < self.cfg.target_radius).to(distance.dtype),
            "effort": action.square().sum(dim=1),
            "leaving": self._outside().to(distance.dtype),
        }

    def terminations(self) -> dict[str, torch.Tensor]:
        return {"left_arena": self._outside()}

    def reset(self, mask: torch.Tensor, rng: EnvRandom) -> None:
        # Draw for every env and keep the masked ones: same work whatever the mask, and no
        # host sync to count them (this runs every step).
        u = rng.rand(2, 2, dtype=self.target.dtype)  # [num_envs, 2, 2]
        start = (2 * u[:, 0] - 1) * self.cfg.start_range
        target = (2 * u[:, 1] - 1) * self.cfg.target_range
        m = mask[:, None]
        self.sim.qpos.copy_(torch.where(m, start, self.sim.qpos))
        self.target.copy_(torch.where(m, target, self.target))

    def success(self, time_out: torch.Tensor) -> torch.Tensor:
        return self._to_target().norm(dim=1) < self.cfg.target_radius
