"""The SB3 agent configs: PPO's, SAC's and TD3's hyperparameters, as `--set agent.KEY=VALUE`
sets them, under SB3's own names."""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

from pydantic import Field, PositiveInt

from labcli.errors import LabError
from labcli.plugins.config import (
    FLOAT,
    AgentConfig,
    check_replay_size,
    mlp_bytes,
    replay_bytes,
    twin_critic_bytes,
)

Activation = Literal["tanh", "relu", "elu"]


class Sb3Config(AgentConfig):
    """What every SB3 learner here shares: its optimizer's step and discount, and SB3's
    VecNormalize in front of it."""

    learning_rate: float = Field(3e-4, gt=0)
    gamma: float = Field(0.99, gt=0, le=1, description="discount factor")
    normalize_obs: bool = Field(True, description="SB3's VecNormalize of observations")
    normalize_reward: bool = Field(False, description="SB3's VecNormalize of rewards")
    clip_obs: float = Field(10.0, gt=0, description="normalized observations are clipped to "
                            "±this")


class Sb3PPOConfig(Sb3Config):
    # The model is rebuilt from the config on resume: every optimization setting applies.
    resumable: ClassVar[frozenset[str]] = AgentConfig.resumable | {
        "learning_rate", "batch_size", "n_epochs", "gamma", "gae_lambda", "clip_range",
        "ent_coef", "vf_coef", "max_grad_norm", "target_kl"}

    n_steps: int = Field(32, gt=0, description="steps per env per iteration")
    batch_size: int = Field(1024, gt=0)
    n_epochs: int = Field(5, gt=0)
    gae_lambda: float = Field(0.95, gt=0, le=1)
    clip_range: float = Field(0.2, gt=0)
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = Field(0.5, gt=0)
    target_kl: float | None = Field(None, gt=0)
    net_arch: list[PositiveInt] = Field(default_factory=lambda: [64, 64])
    activation: Activation = "tanh"
    log_std_init: float = 0.0

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


class Sb3OffPolicyConfig(Sb3Config):
    """What SB3's SAC and TD3 share: a replay buffer every transition is reused from, where PPO
    uses each rollout once, and twin Q critics with soft-updated targets."""

    # The model is rebuilt from the config on resume: its optimization settings apply.
    resumable: ClassVar[frozenset[str]] = AgentConfig.resumable | {
        "learning_rate", "learning_starts", "batch_size", "tau", "gamma", "gradient_steps"}
    actor_outputs: ClassVar[int] = 1  # the actor's outputs per action

    train_freq: int = Field(8, gt=0, description="steps per env per iteration; gradient_steps "
                            "updates follow them")
    gradient_steps: int = Field(8, gt=0, description="updates per iteration")
    buffer_size: int = Field(1_000_000, gt=0, description="transitions the replay buffer holds "
                             "(over all envs); the newest checkpoint saves it")
    learning_starts: int = Field(100, ge=0, description="env steps (of all envs) of uniform "
                                 "random actions before the first update")
    batch_size: int = Field(256, gt=0, description="transitions per gradient step")
    tau: float = Field(0.005, gt=0, le=1, description="target networks' soft-update rate")
    net_arch: list[PositiveInt] = Field(default_factory=lambda: [256, 256],
                                        description="hidden layers of the actor and each critic")
    activation: Activation = "relu"

    def check(self, num_envs: int) -> None:
        check_replay_size("agent.buffer_size", self.buffer_size, num_envs)
        if self.batch_size > self.buffer_size:  # SB3 would draw each batch with repeats
            raise LabError(f"agent.batch_size={self.batch_size:,} is more than "
                           f"agent.buffer_size={self.buffer_size:,} transitions",
                           "use a smaller batch or a larger buffer")

    def memory(self, num_envs: int, observations: int, actions: int) -> dict[str, int]:
        # SB3's replay buffer holds a reward, a done and a time-out flag besides the
        # observations and actions of a transition.
        return {
            "agent.buffer_size": replay_bytes(self.buffer_size, observations, actions, 3),
            "agent.net_arch": twin_critic_bytes(observations, self.net_arch, actions,
                                                self.actor_outputs),
        }


# SB3's ent_coef: a number, or "auto" (learned from 1.0) or "auto_<initial value>".
EntropyCoefficient = (Annotated[float, Field(gt=0)]
                      | Annotated[str, Field(pattern=r"^auto(_\d+(\.\d*)?([eE]-?\d+)?)?$")])


class Sb3SACConfig(Sb3OffPolicyConfig):
    """SB3's Soft Actor-Critic: a tanh-squashed Gaussian actor whose entropy is kept near a
    target."""

    actor_outputs: ClassVar[int] = 2  # a mean and a log std per action

    ent_coef: EntropyCoefficient = Field(
        "auto", description='entropy coefficient: a number, or "auto" (learned, from 1.0) or '
        '"auto_0.1" (learned, from 0.1)')
    target_entropy: float | Literal["auto"] = Field(
        "auto", description='the learned coefficient\'s entropy target; "auto": minus the '
        "action count")


class Sb3TD3Config(Sb3OffPolicyConfig):
    """SB3's TD3: a deterministic actor explored with Gaussian noise, updated every policy_delay
    critic updates, its target actions smoothed with clipped noise."""

    resumable: ClassVar[frozenset[str]] = Sb3OffPolicyConfig.resumable | {
        "policy_delay", "target_policy_noise", "target_noise_clip", "action_noise_sigma"}

    policy_delay: int = Field(2, gt=0, description="critic updates per actor update")
    target_policy_noise: float = Field(0.2, ge=0, description="std of the target actions' noise "
                                       "(actions in [-1, 1])")
    target_noise_clip: float = Field(0.5, ge=0, description="the target actions' noise is "
                                     "clipped to ±this")
    action_noise_sigma: float = Field(0.1, ge=0, description="std of the Gaussian noise added "
                                      "to actions while training (actions in [-1, 1]); 0: none")
