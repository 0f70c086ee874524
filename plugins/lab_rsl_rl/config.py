"""The RSL-RL agent config: PPO's and the actor-critic's settings, as `--set agent.KEY=VALUE`
sets them."""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import Field, PositiveInt

from labcli.plugins.config import FLOAT, AgentConfig, mlp_bytes, too_many_batches


class RslRlPpoConfig(AgentConfig):
    """RSL-RL's PPO and actor-critic settings, named as in Isaac Lab's RslRlPpoAlgorithmCfg."""

    # PPO is rebuilt from the config on resume; the learning rate, restored with the optimizer,
    # is set again when a resume changes it.
    resumable: ClassVar[frozenset[str]] = AgentConfig.resumable | {
        "learning_rate", "schedule", "desired_kl", "num_learning_epochs", "num_mini_batches",
        "gamma", "lam", "clip_param", "entropy_coef", "value_loss_coef",
        "use_clipped_value_loss", "max_grad_norm", "cuda_graph", "kl_grows_with_ranks",
        "symmetry_augmentation", "mirror_loss_coef"}

    num_steps_per_env: int = Field(24, gt=0, description="steps per env per iteration")
    actor_hidden_dims: list[PositiveInt] = Field(default_factory=lambda: [64, 64])
    critic_hidden_dims: list[PositiveInt] = Field(default_factory=lambda: [64, 64])
    activation: Literal["elu", "relu", "tanh", "selu", "lrelu", "gelu", "swish"] = "elu"
    init_noise_std: float = Field(1.0, gt=0, description="initial std of the Gaussian actions")
    empirical_normalization: bool = Field(
        True, description="normalize observations by running mean and std (saved in checkpoints)")
    learning_rate: float = Field(1e-3, gt=0)
    schedule: Literal["adaptive", "fixed"] = "adaptive"
    desired_kl: float | None = Field(0.01, gt=0, description="KL target of the adaptive lr")
    # The ranks' batch is N times one's, and its gradient's noise smaller; without a larger
    # target the adaptive lr keeps each update's step as small, and go1-flat took as many
    # iterations to success on 2 and 4 GPUs as on one (docs/scale.md, "Several GPUs").
    kl_grows_with_ranks: bool = Field(
        True, description="with N data-parallel ranks, the KL target is desired_kl × N")
    num_learning_epochs: int = Field(5, gt=0)
    num_mini_batches: int = Field(4, gt=0)
    gamma: float = Field(0.99, gt=0, le=1)
    lam: float = Field(0.95, gt=0, le=1)
    clip_param: float = Field(0.2, gt=0)
    entropy_coef: float = 0.005
    value_loss_coef: float = 1.0
    use_clipped_value_loss: bool = True
    max_grad_norm: float = Field(1.0, gt=0)
    cuda_graph: bool = Field(True, description="on a GPU, replay each update's mini-batch "
                             "steps as one CUDA graph (false: RSL-RL's own update)")
    # RSL-RL's symmetry extension, with the mirror image the task's robot description declares
    # (labcli.envs.mdp.symmetry); on a GPU inside the update's CUDA graph too.
    symmetry_augmentation: bool = Field(
        False, description="learn from each mini-batch and its left-right mirror image")
    mirror_loss_coef: float = Field(
        0.0, ge=0, description="weight of the mirror loss: the policy's action for a mirrored "
        "observation against its mirrored action (0: off)")

    def kl_target(self, world_size: int) -> float | None:
        """The adaptive learning rate's KL target in a run of `world_size` ranks."""
        if self.desired_kl is None or not self.kl_grows_with_ranks:
            return self.desired_kl
        return self.desired_kl * world_size

    def check(self, num_envs: int) -> None:
        samples = self.num_steps_per_env * num_envs
        if self.num_mini_batches > samples:
            raise too_many_batches("agent.num_mini_batches", self.num_mini_batches, samples)

    @property
    def symmetric(self) -> bool:
        return self.symmetry_augmentation or self.mirror_loss_coef > 0

    def check_env(self, env: Any) -> None:
        if self.symmetric:
            from labcli.envs.mdp.symmetry import mirror_of_env

            mirror_of_env(env)

    def memory(self, num_envs: int, observations: int, actions: int) -> dict[str, int]:
        # RSL-RL's storage: actor and critic observations, actions, their means and std, and
        # six floats a sample.
        samples = self.num_steps_per_env * num_envs
        return {
            "agent.num_steps_per_env": samples * (2 * observations + 3 * actions + 6) * FLOAT,
            "agent.actor_hidden_dims": mlp_bytes([observations, *self.actor_hidden_dims,
                                                  actions]),
            "agent.critic_hidden_dims": mlp_bytes([observations, *self.critic_hidden_dims, 1]),
        }
