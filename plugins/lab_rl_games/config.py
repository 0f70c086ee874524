"""The rl_games agent config: its a2c_continuous (PPO) settings under rl_games' own names, as
`--set agent.KEY=VALUE` sets them. Defaults are Isaac Lab's rl_games PPO settings."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, PositiveInt

from labcli.errors import LabError
from labcli.plugins.config import FLOAT, AgentConfig, mlp_bytes


class RlGamesPPOConfig(AgentConfig):
    # The agent is rebuilt from the config on resume; the learning rate, restored with the
    # optimizer (the adaptive schedule moves it), is set again when a resume changes it.
    resumable: ClassVar[frozenset[str]] = AgentConfig.resumable | {
        "learning_rate", "kl_threshold", "mini_epochs", "gamma", "tau", "e_clip",
        "entropy_coef", "critic_coef", "grad_norm", "truncate_grads", "clip_value",
        "bounds_loss_coef", "reward_scale"}

    horizon_length: int = Field(16, gt=0, description="steps per env per iteration")
    mini_epochs: int = Field(8, gt=0)
    minibatch_size_per_env: int = Field(
        4, gt=0, description="samples per env in a mini-batch (rl_games' minibatch_size is "
                             "this times the env count)")
    learning_rate: float = Field(5e-4, gt=0)
    lr_schedule: Literal["adaptive", "constant"] = Field(
        "adaptive", description="adaptive: scale the learning rate to keep the KL near "
                                "kl_threshold")
    kl_threshold: float = Field(0.008, gt=0)
    gamma: float = Field(0.99, gt=0, le=1)
    tau: float = Field(0.95, gt=0, le=1, description="GAE lambda")
    e_clip: float = Field(0.2, gt=0)
    entropy_coef: float = 0.0
    critic_coef: float = Field(4.0, gt=0)
    grad_norm: float = Field(1.0, gt=0)
    truncate_grads: bool = True
    clip_value: bool = True
    bounds_loss_coef: float = Field(1e-4, ge=0)
    reward_scale: float = Field(1.0, gt=0, description="rewards are multiplied by this")
    normalize_input: bool = True
    normalize_value: bool = True
    normalize_advantage: bool = True
    units: list[PositiveInt] = Field(default_factory=lambda: [32, 32])
    activation: Literal["elu", "relu", "tanh", "selu"] = "elu"
    sigma_init: float = Field(0.0, description="initial log std of the actions")

    def check(self, num_envs: int) -> None:
        # rl_games' batch is horizon_length x envs, its mini-batch minibatch_size_per_env x envs:
        # it refuses a mini-batch that does not divide the batch.
        per_env, horizon = self.minibatch_size_per_env, self.horizon_length
        if per_env > horizon or horizon % per_env:
            raise LabError(f"agent.minibatch_size_per_env={per_env} does not divide the "
                           f"{horizon} samples each env gives per iteration "
                           "(agent.horizon_length)",
                           f"use a divisor of {horizon}, e.g. {_largest_divisor(horizon, per_env)}")

    def memory(self, num_envs: int, observations: int, actions: int) -> dict[str, int]:
        # rl_games' experience buffer: observations, actions, means and sigmas, and five floats
        # a sample (values, rewards, log-probabilities, dones, returns); then the shared
        # actor-critic MLP.
        return {
            "agent.horizon_length": self.horizon_length * num_envs
            * (observations + 3 * actions + 5) * FLOAT,
            "agent.units": mlp_bytes([observations, *self.units, actions + 1]),
        }


def _largest_divisor(n: int, at_most: int) -> int:
    return max(d for d in range(1, min(n, at_most) + 1) if n % d == 0)
