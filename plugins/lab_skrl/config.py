"""The skrl agent config: PPO's settings, as `--set agent.KEY=VALUE` sets them."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, PositiveInt

from labcli.plugins.config import FLOAT, AgentConfig, mlp_bytes, too_many_batches


class SkrlPPOConfig(AgentConfig):
    # The agent is rebuilt from the config on resume; the learning rate, restored with the
    # optimizer, is set again when a resume changes it.
    resumable: ClassVar[frozenset[str]] = AgentConfig.resumable | {
        "learning_rate", "learning_epochs", "mini_batches", "discount_factor", "gae_lambda",
        "ratio_clip", "value_clip", "entropy_loss_scale", "value_loss_scale", "grad_norm_clip",
        "reward_scale", "desired_kl", "cuda_graph"}

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
    cuda_graph: bool = Field(True, description="on a GPU, replay each update's mini-batch "
                             "steps as one CUDA graph (false: skrl's own update)")

    def check(self, num_envs: int) -> None:
        samples = self.rollouts * num_envs
        if self.mini_batches > samples:  # skrl would loop without end on empty batches
            raise too_many_batches("agent.mini_batches", self.mini_batches, samples)

    def memory(self, num_envs: int, observations: int, actions: int) -> dict[str, int]:
        # skrl's memory: observations, actions, and seven floats a sample.
        return {
            "agent.rollouts": self.rollouts * num_envs * (observations + actions + 7) * FLOAT,
            "agent.hidden_sizes": mlp_bytes([observations, *self.hidden_sizes, actions])
            + mlp_bytes([observations, *self.hidden_sizes, 1]),
        }
