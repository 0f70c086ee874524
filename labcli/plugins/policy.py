"""What a framework's `load_policy` returns: the deterministic policy with its observation
normalizer inside, so that what is played and exported is exactly what was trained."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from torch import nn


class ObsNormalizer(nn.Module):
    """(obs - mean) / sqrt(var + eps), clipped: the frozen form of a running normalizer."""

    def __init__(self, mean: torch.Tensor, var: torch.Tensor, eps: float, clip: float | None):
        super().__init__()
        self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float32).clone())
        self.register_buffer("std", torch.sqrt(torch.as_tensor(var, dtype=torch.float32) + eps))
        self.clip = clip

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        out = (obs - self.mean) / self.std
        return out if self.clip is None else out.clamp(-self.clip, self.clip)


class Policy(nn.Module):
    """Observation → deterministic action in [-1, 1], with the observation normalizer inside,
    so that what is played and exported is exactly what was trained."""

    def __init__(self, actor: nn.Module, normalizer: nn.Module | None = None):
        super().__init__()
        self.normalizer = normalizer if normalizer is not None else nn.Identity()
        self.actor = actor

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.actor(self.normalizer(obs)).clamp(-1.0, 1.0)


@contextlib.contextmanager
def one_torch_thread(device: str) -> Iterator[None]:
    """On CPU, run the learner on one torch thread. Policy-sized MLPs gain nothing from more:
    they only add synchronization, and their spinning threads fight MuJoCo's for the cores
    (measured on 2 cores: 6 RSL-RL cartpole iterations took 28 s with 2 threads, 2 s with 1;
    an skrl backward pass 44 ms against 1 ms)."""
    if torch.device(device).type != "cpu":
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)
