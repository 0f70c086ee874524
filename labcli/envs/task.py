"""The public task API: batched torch functions over a Sim, configured by a `TaskConfig`.

A task is written once with torch operations on `[num_envs, ...]` tensors, so it runs unchanged
on every backend. Plugins register a `TaskSpec` (labcli/envs/spec.py) naming it.
"""

from __future__ import annotations

from typing import ClassVar

import torch

from labcli.envs.config import TaskConfig
from labcli.envs.sim import Sim


class Task:
    """Batched MDP terms over `sim`; subclasses override the methods below with torch code."""

    observation_names: ClassVar[list[str]]
    action_names: ClassVar[list[str]]

    def __init__(self, cfg: TaskConfig, sim: Sim):
        self.cfg = cfg
        self.sim = sim

    def apply_actions(self, actions: torch.Tensor) -> None:
        """Turn clipped actions in [-1, 1] into controls; the default scales them into ctrl."""
        torch.mul(actions, self.cfg.action_scale, out=self.sim.ctrl)

    def update(self) -> None:
        """Called by the env each time the sim's state changed (after the physics steps, a reset
        or a restore), before it reads any term: compute here, once, what several terms share
        (cartpole: the wrapped pole angle), instead of once per term. Write the results into
        tensors made once (`out=`, in-place ops): on a GPU the env step replays as a CUDA graph,
        which writes into the tensors it was captured with. The default does nothing."""

    def observations(self) -> torch.Tensor:
        raise NotImplementedError

    def reward_terms(self) -> dict[str, torch.Tensor]:
        """Unweighted reward terms by name; the weights come from `cfg.reward_weights`."""
        raise NotImplementedError

    def terminations(self) -> dict[str, torch.Tensor]:
        """Boolean `[num_envs]` per termination cause (time-outs are the env's business)."""
        return {}

    def reset(self, mask: torch.Tensor, generator: torch.Generator) -> None:
        """Randomize the state of the envs in `mask`; the sim already put them at the defaults."""

    def success(self, time_out: torch.Tensor) -> torch.Tensor:
        """Whether each ending episode succeeded, judged on its final state."""
        return torch.zeros_like(time_out)
