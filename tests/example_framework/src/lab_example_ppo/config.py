"""The agent config: the library's settings, as `--set agent.KEY=VALUE` sets them. pydantic
checks each value; `check` refuses what cannot work with the env count before anything runs."""

from __future__ import annotations

from typing import ClassVar

from pydantic import Field, PositiveInt

from labcli.plugins.config import AgentConfig, too_many_batches


class ExamplePPOConfig(AgentConfig):
    # What a resume may change: the rest (the network, the rollout) the checkpoint is made of.
    resumable: ClassVar[frozenset[str]] = AgentConfig.resumable | {"learning_rate"}

    steps_per_env: int = Field(16, gt=0, description="steps per env per iteration")
    epochs: int = Field(4, gt=0)
    minibatches: int = Field(4, gt=0)
    learning_rate: float = Field(3e-4, gt=0)
    gamma: float = Field(0.99, gt=0, le=1)
    lam: float = Field(0.95, gt=0, le=1)
    clip: float = Field(0.2, gt=0)
    hidden: list[PositiveInt] = Field(default_factory=lambda: [64, 64])
    normalize_obs: bool = True

    def check(self, num_envs: int) -> None:
        samples = self.steps_per_env * num_envs
        if self.minibatches > samples:
            raise too_many_batches("agent.minibatches", self.minibatches, samples)
