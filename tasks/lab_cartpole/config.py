"""Cartpole's settings, as `--set env.KEY=VALUE` sets them."""

from __future__ import annotations

import math

from pydantic import Field

from labcli.envs.config import TaskConfig


class CartpoleConfig(TaskConfig):
    # episode_length_s (5 s) and decimation (2) keep TaskConfig's defaults and constraints.
    action_scale: float = Field(40.0, description="newtons on the cart at action 1")
    # Isaac Lab's cartpole weights. The squared angle makes a spinning pole cost (1 - pi^2/3 per
    # step on average, against ~1 balanced): with a bounded "upright" term instead, spinning
    # earned 78% of the best return, a plateau where learners sat without balancing.
    reward_weights: dict[str, float] = Field(default_factory=lambda: {
        "alive": 1.0, "terminating": -2.0, "pole_angle": -1.0, "cart_vel": -0.01,
        "pole_vel": -0.005,
    })
    cart_bound: float = Field(3.0, gt=0, description="metres; beyond it the episode ends")
    reset_cart_pos: tuple[float, float] = (-1.0, 1.0)
    reset_pole_angle: tuple[float, float] = (-0.25 * math.pi, 0.25 * math.pi)
    reset_cart_vel: tuple[float, float] = (-0.5, 0.5)
    reset_pole_vel: tuple[float, float] = (-0.5, 0.5)
    success_angle: float = Field(0.2, gt=0, description="radians from upright at time-out")
