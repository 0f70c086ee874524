"""Cartpole in the spirit of Isaac Lab's: bring the pole upright from up to ±45° and hold it,
keeping the cart on its rail. Episodes end after 5 s or when the cart leaves its bounds."""

from __future__ import annotations

import math

import torch

from lab_cartpole.config import CartpoleConfig
from labcli.envs.random import EnvRandom
from labcli.envs.sim import Sim
from labcli.envs.task import Task


class Cartpole(Task):
    cfg: CartpoleConfig
    observation_names = ["cart_pos", "pole_angle", "cart_vel", "pole_vel"]
    action_names = ["cart_force"]
    observation_units = {
        "cart_pos": "m along the rail (+x), 0 at its centre",
        "pole_angle": "rad from upright, wrapped to [-pi, pi); positive tips the pole's top "
                      "toward +x",
        "cart_vel": "m/s along +x",
        "pole_vel": "rad/s, positive as pole_angle grows",
    }
    action_units = {"cart_force": "N along +x"}

    def __init__(self, cfg: CartpoleConfig, sim: Sim):
        super().__init__(cfg, sim)
        # Built once: a tensor made from Python numbers on a GPU is a host-to-device copy that
        # waits for the GPU, and reset runs every step.
        ranges = torch.tensor(
            [cfg.reset_cart_pos, cfg.reset_pole_angle, cfg.reset_cart_vel, cfg.reset_pole_vel],
            dtype=sim.qpos.dtype, device=sim.qpos.device)
        # Tiled to [num_envs, 4]: one flat loop, where broadcasting [4] walks the envs one by one.
        low, width = ranges[:, 0], ranges[:, 1] - ranges[:, 0]
        self._reset_low, self._reset_width = (x.expand(sim.num_envs, 4).contiguous()
                                              for x in (low, width))
        # Drawn into each step: no allocation, and its position and velocity halves are views.
        self._sample = torch.empty_like(self._reset_low)
        self._sample_pos, self._sample_vel = self._sample.split(2, dim=1)
        self._ones = torch.ones_like(sim.qpos[:, 0])  # the "alive" term; the env only reads it
        # Views of the live state columns, taken once: indexing costs as much as an op on them.
        self._cart_pos, self._pole_pos = sim.qpos.unbind(1)
        self._cart_vel, self._pole_vel = sim.qvel.unbind(1)
        self.pole_angle = torch.empty_like(self._pole_pos)  # wrapped to [-pi, pi)
        self.out_of_bounds = torch.empty_like(self._cart_pos, dtype=torch.bool)
        self.update()  # the env asks for the reward terms' names before the first reset

    def update(self) -> None:
        # Each term below reads these: computed once per state (after the physics steps, after
        # a reset), not once per term. In place: a step replayed as a CUDA graph writes into
        # the tensors it was captured with, which a rebound attribute would no longer be.
        torch.add(self._pole_pos, math.pi, out=self.pole_angle).remainder_(2 * math.pi)
        self.pole_angle.sub_(math.pi)
        torch.gt(self._cart_pos.abs(), self.cfg.cart_bound, out=self.out_of_bounds)

    def observations(self) -> torch.Tensor:
        return torch.stack((self._cart_pos, self.pole_angle, self._cart_vel, self._pole_vel),
                           dim=1)

    def reward_terms(self) -> dict[str, torch.Tensor]:
        angle = self.pole_angle
        return {
            "alive": self._ones,
            "terminating": self.out_of_bounds.to(angle.dtype),
            "pole_angle": angle.square(),  # radians from upright, squared
            "cart_vel": self._cart_vel.abs(),
            "pole_vel": self._pole_vel.abs(),
        }

    def terminations(self) -> dict[str, torch.Tensor]:
        return {"cart_out_of_bounds": self.out_of_bounds}

    def reset(self, mask: torch.Tensor, rng: EnvRandom) -> None:
        u = rng.uniform_(self._sample)
        # Not addcmul: its fused multiply-add rounds differently, and seeded runs would change.
        u.mul_(self._reset_width).add_(self._reset_low)
        m = mask[:, None]
        # In place (out= is the state itself): no temporary state and no copy back.
        torch.where(m, self._sample_pos, self.sim.qpos, out=self.sim.qpos)
        torch.where(m, self._sample_vel, self.sim.qvel, out=self.sim.qvel)

    def success(self, time_out: torch.Tensor) -> torch.Tensor:
        # Only time-outs are judged, and leaving the rail ends an episode before its time-out:
        # the angle alone decides.
        return self.pole_angle.abs() < self.cfg.success_angle
