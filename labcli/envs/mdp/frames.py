"""The frames of each observation term that the policy sees: its last `history_length` ones,
oldest first, and frames that reach it `delay` control steps late (`ObsTerm`'s settings).
Built by `RobotTask` only where a term asks for either: otherwise a step costs nothing more."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch


def column_names(names: list[str], frames: int) -> list[str]:
    """A term's input columns for `frames` frames, oldest first: `name@t-k` for the frame k
    control steps before the newest, which keeps the term's own names."""
    return [f"{name}@t-{age}" if age else name
            for age in range(frames - 1, -1, -1) for name in names]


class ObservationFrames:
    """Each env's observation frames (after bias, noise, clip and scale) of the last control
    steps, `window[:, k]` k steps old, from which each input column is gathered at once: the
    term's frame of its age in its history plus the env's lag for the term, drawn at each
    episode's start. A frame before an episode's first is its first.

    `__call__(frame)` gives a step's input and notes `frame` as the newest; `advance()`, at
    the next step's start, keeps it: a step may observe twice (an ended env's last frame,
    then its next episode's first), and only what it returned is kept."""

    carried = ("window", "lag", "fresh")

    def __init__(self, task: Any, terms: Sequence[Any], widths: Sequence[int]):
        n, dev = task.num_envs, task.ones.device
        oldest = max(t.frames - 1 + t.delay[1] for t in terms)
        self.task, self.width = task, sum(widths)
        # Envs first, as all state a task carries (an env shard's is its rows).
        self.window = torch.zeros(n, oldest + 1, self.width, dtype=task.ones.dtype, device=dev)
        self.lag = torch.zeros(n, len(terms), dtype=torch.long, device=dev)
        self.fresh = torch.ones(n, dtype=torch.bool, device=dev)
        source, term, age, start = [], [], [], 0
        for i, (cfg, width) in enumerate(zip(terms, widths, strict=True)):
            for frame_age in range(cfg.frames - 1, -1, -1):
                source += range(start, start + width)
                term += [i] * width
                age += [frame_age] * width
            start += width
        self.source = torch.tensor(source, device=dev)
        self.term = torch.tensor(term, device=dev)
        self.age = torch.tensor(age, device=dev)
        self.low = torch.tensor([t.delay[0] for t in terms], device=dev)
        self.count = torch.tensor([t.delay[1] - t.delay[0] + 1 for t in terms], device=dev)
        self.draw = torch.empty(n, len(terms), device=dev)
        self.out = torch.empty(n, len(source), dtype=task.ones.dtype, device=dev)

    def reset(self, mask: torch.Tensor) -> None:
        self.task.rng.uniform_(self.draw)
        lag = torch.minimum(self.draw.mul(self.count).long(), self.count - 1).add_(self.low)
        torch.where(mask[:, None], lag, self.lag, out=self.lag)
        self.fresh.logical_or_(mask)

    def __call__(self, frame: torch.Tensor) -> torch.Tensor:
        self.window[:, 0] = frame
        ages = self.lag[:, self.term].add_(self.age).masked_fill_(self.fresh[:, None], 0)
        flat = self.window.view(self.window.shape[0], -1)
        return torch.gather(flat, 1, ages.mul_(self.width).add_(self.source), out=self.out)

    def advance(self) -> None:
        """The newest frame kept as one step old; a fresh env's for each older one too."""
        self.window[:, 1:] = self.window[:, :-1].clone()
        torch.where(self.fresh[:, None, None], self.window[:, :1], self.window, out=self.window)
        self.fresh.zero_()
