"""The skrl agent config: PPO's settings, as `--set agent.KEY=VALUE` sets them."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, PositiveInt

from labcli.plugins.config import AgentConfig


class SkrlPPOConfig(AgentConfig):
    rollouts: int = Field(16, gt=0, description="steps per env per iteration")
    learning_epochs: int = Field(8, gt=0)
    mini_batches: int = Field(8, gt=0)
    discount_factor: float = Field(0.99, gt=0, le=1)
    gae_lambda: float = Field(0.95, gt=0, le=1)
    learning_rate: float = Field(1e-3, gt=0)
    kl_adaptive_lr: bool = Field(True, description="adapt the learning rate to desired_kl")
    desired_kl: float = Field(0.008, gt=0, description="KL target of the adaptive learning rate")
    ratio_clip: float = Field(0.2, gt=0)
    value_clip: float = Field(0.2, ge=0, description="0 turns value clipping off")
    entropy_loss_scale: float = 0.0
    value_loss_scale: float = Field(2.0, gt=0)
    grad_norm_clip: float = Field(1.0, ge=0, description="0 turns gradient clipping off")
    reward_scale: float = Field(1.0, gt=0, description="rewards are multiplied by this")
    hidden_sizes: list[PositiveInt] = Field(default_factory=lambda: [32, 32])
    activation: Literal["tanh", "relu", "elu"] = "elu"
    init_log_std: float = 0.0
    normalize_obs: bool = True
    normalize_value: bool = True
    clip_obs: float = Field(5.0, gt=0, description="normalized observations are clipped to ±this")
