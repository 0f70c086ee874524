"""`AgentConfig`: the settings every framework has, which a framework plugin's pydantic config
subclasses with its library's hyperparameters. Kept apart from the spec that names it, so that
loading plugins imports no pydantic."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class AgentConfig(BaseModel):
    """Settings every framework has; a plugin subclasses it with its library's hyperparameters."""

    # NaN and inf are never meant: they would only surface later as a diverged run.
    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)

    max_iterations: int = Field(100, gt=0, description="rollout + update cycles in total")
    save_interval: int = Field(50, gt=0, description="iterations between checkpoints")
    seed: int = Field(0, ge=0, lt=2**32, description="seeds the env, torch, NumPy and Python")
