"""The SB3 agent config: PPO's hyperparameters, as `--set agent.KEY=VALUE` sets them."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from labcli.plugins.config import AgentConfig


class Sb3PPOConfig(AgentConfig):
    n_steps: int = Field(32, gt=0, description="steps per env per iteration")
    batch_size: int = Field(1024, gt=0)
    n_epochs: int = Field(5, gt=0)
    learning_rate: float = Field(3e-4, gt=0)
    gamma: float = Field(0.99, gt=0, le=1)
    gae_lambda: float = Field(0.95, gt=0, le=1)
    clip_range: float = Field(0.2, gt=0)
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float | None = None
    net_arch: list[int] = Field(default_factory=lambda: [64, 64])
    activation: Literal["tanh", "relu", "elu"] = "tanh"
    log_std_init: float = 0.0
    normalize_obs: bool = True
    normalize_reward: bool = False
    clip_obs: float = Field(10.0, gt=0)
