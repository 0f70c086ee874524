"""The SB3 agent config: PPO's hyperparameters, as `--set agent.KEY=VALUE` sets them."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, PositiveInt

from labcli.errors import LabError
from labcli.plugins.config import FLOAT, AgentConfig, mlp_bytes


class Sb3PPOConfig(AgentConfig):
    # The model is rebuilt from the config on resume: every optimization setting applies.
    resumable: ClassVar[frozenset[str]] = AgentConfig.resumable | {
        "learning_rate", "batch_size", "n_epochs", "gamma", "gae_lambda", "clip_range",
        "ent_coef", "vf_coef", "max_grad_norm", "target_kl"}

    n_steps: int = Field(32, gt=0, description="steps per env per iteration")
    batch_size: int = Field(1024, gt=0)
    n_epochs: int = Field(5, gt=0)
    learning_rate: float = Field(3e-4, gt=0)
    gamma: float = Field(0.99, gt=0, le=1)
    gae_lambda: float = Field(0.95, gt=0, le=1)
    clip_range: float = Field(0.2, gt=0)
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = Field(0.5, gt=0)
    target_kl: float | None = Field(None, gt=0)
    net_arch: list[PositiveInt] = Field(default_factory=lambda: [64, 64])
    activation: Literal["tanh", "relu", "elu"] = "tanh"
    log_std_init: float = 0.0
    normalize_obs: bool = True
    normalize_reward: bool = False
    clip_obs: float = Field(10.0, gt=0)

    def check(self, num_envs: int) -> None:
        if self.n_steps * num_envs < 2:  # SB3 asserts it: no advantage can be normalized
            raise LabError(f"agent.n_steps={self.n_steps} with {num_envs} env(s) is a rollout of "
                           "one sample", "use at least 2 steps or envs")

    def memory(self, num_envs: int, observations: int, actions: int) -> dict[str, int]:
        # SB3's rollout buffer: observations, actions, and six floats a sample (rewards,
        # returns, starts, values, log-probabilities, advantages).
        return {
            "agent.n_steps": self.n_steps * num_envs * (observations + actions + 6) * FLOAT,
            "agent.net_arch": mlp_bytes([observations, *self.net_arch, actions])
            + mlp_bytes([observations, *self.net_arch, 1]),
        }
