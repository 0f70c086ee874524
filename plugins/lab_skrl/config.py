"""The skrl agent configs: PPO's, SAC's and TD3's settings, as `--set agent.KEY=VALUE` sets them."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, PositiveInt

from labcli.plugins.config import (
    FLOAT,
    AgentConfig,
    check_replay_size,
    mlp_bytes,
    replay_bytes,
    too_many_batches,
    twin_critic_bytes,
)


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


class OffPolicyConfig(AgentConfig):
    """What skrl's off-policy learners (SAC, TD3) share: a replay memory every transition is
    reused from, where PPO uses each rollout once, and twin critics with soft-updated
    targets."""

    # The agent is rebuilt from the config on resume: its optimization settings apply.
    resumable: ClassVar[frozenset[str]] = AgentConfig.resumable | {
        "learning_rate", "gradient_steps", "batch_size", "discount_factor", "polyak",
        "grad_norm_clip", "reward_scale"}
    actor_outputs: ClassVar[int] = 1  # the actor's outputs per action

    rollouts: int = Field(8, gt=0, description="steps per env per iteration; at its end, "
                          "gradient_steps updates for each step")
    buffer_size: int = Field(1_000_000, gt=0, description="transitions the replay memory holds "
                             "(over all envs); every checkpoint saves it")
    batch_size: int = Field(256, gt=0, description="transitions per gradient step")
    gradient_steps: int = Field(1, gt=0, description="updates after each env step")
    learning_starts: int = Field(100, ge=0, description="steps per env of uniform random actions "
                                 "before the first update")
    discount_factor: float = Field(0.99, gt=0, le=1)
    polyak: float = Field(0.005, gt=0, le=1, description="target networks' soft-update rate")
    learning_rate: float = Field(3e-4, gt=0)
    grad_norm_clip: float = Field(0.0, ge=0, description="0 turns gradient clipping off")
    reward_scale: float = Field(1.0, gt=0, description="rewards are multiplied by this")
    hidden_sizes: list[PositiveInt] = Field(default_factory=lambda: [256, 256])
    activation: Literal["tanh", "relu", "elu"] = "relu"
    action_bound: float = Field(1.0, gt=0, description="the actor's actions are tanh-squashed "
                                "to ±this")
    normalize_obs: bool = True
    clip_obs: float = Field(5.0, gt=0, description="normalized observations are clipped to ±this")

    def check(self, num_envs: int) -> None:
        check_replay_size("agent.buffer_size", self.buffer_size, num_envs)

    def memory(self, num_envs: int, observations: int, actions: int) -> dict[str, int]:
        # The replay memory holds a reward and a termination besides the observations and
        # actions of a transition.
        return {
            "agent.buffer_size": replay_bytes(self.buffer_size, observations, actions, 2),
            "agent.hidden_sizes": twin_critic_bytes(observations, self.hidden_sizes, actions,
                                                    self.actor_outputs),
        }


class SkrlSACConfig(OffPolicyConfig):
    """skrl's Soft Actor-Critic: a stochastic actor whose entropy is kept near a target."""

    actor_outputs: ClassVar[int] = 2  # a mean and a log std per action

    learn_entropy: bool = True
    initial_entropy_value: float = Field(0.2, gt=0)
    target_entropy: float | None = Field(None, description="null: minus the action count")


class SkrlTD3Config(OffPolicyConfig):
    """skrl's TD3: a deterministic actor explored with Gaussian noise, updated every
    policy_delay critic updates, its target actions smoothed with clipped noise."""

    exploration_noise: float = Field(0.1, ge=0, description="std of the noise added to actions, "
                                     "as a fraction of action_bound")
    policy_delay: int = Field(2, gt=0, description="critic updates per actor update")
    smoothing_noise: float = Field(0.2, ge=0, description="std of the target actions' noise, "
                                   "as a fraction of action_bound")
    smoothing_clip: float = Field(0.5, ge=0, description="the target actions' noise is clipped "
                                  "to ±this fraction of action_bound")
