"""The env's random numbers: a generator per fixed block of envs, so that what an env draws does
not depend on how many envs share its batch (one process, or the cpu backend's env shards); on a
GPU, which has no shards, one generator for all envs."""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Iterator

import numpy as np
import torch

# Envs are cut into this many blocks (fewer when there are fewer envs), whatever the threads or
# processes: the most env shards the cpu backend can make.
BLOCKS = 16


def block_bounds(total: int, blocks: int = BLOCKS) -> list[int]:
    """Where the `blocks` blocks of `total` envs start (fewer if fewer envs), and the end:
    `[0, ..., total]`."""
    count = min(blocks, total)
    return [b * total // count for b in range(count + 1)]


class EnvRandom:
    """Draws for envs `[first, first + num_envs)` of `total`, each block from its own generator:
    fill `[num_envs, ...]` tensors with `uniform_` or `normal_` instead of passing a
    `torch.Generator`, and every env gets the same numbers in one batch or in shards."""

    def __init__(self, num_envs: int, device: torch.device | str, first: int = 0,
                 total: int | None = None, reads_masks: bool | None = None,
                 blocks: int = BLOCKS):
        """`reads_masks`: whether `only_for` reads its mask on the host (by default on the
        CPU); not in a step that is replayed or compiled, which cannot read it. `blocks`: 1 on
        a GPU, where every block draws at every step and each block's draw is a kernel of its
        own (g1-flat's step: 128 random kernels with 16 blocks, 8 with one)."""
        total = num_envs if total is None else total
        bounds = block_bounds(total, blocks)
        self.blocks = [b for b in range(len(bounds) - 1)
                       if first <= bounds[b] and bounds[b + 1] <= first + num_envs]
        if not self.blocks or bounds[self.blocks[0]] != first \
                or bounds[self.blocks[-1] + 1] != first + num_envs:
            raise ValueError(f"envs [{first}, {first + num_envs}) of {total} are not whole blocks")
        self._rows = [slice(bounds[b] - first, bounds[b + 1] - first) for b in self.blocks]
        self.num_envs, self.device = num_envs, torch.device(device)
        self._reads_masks = (self.device.type == "cpu" if reads_masks is None
                             else reads_masks)  # asked on every `only_for`
        self.generators = [torch.Generator(device) for _ in self.blocks]
        self._ends = torch.tensor([r.stop for r in self._rows])
        self._equal = len({r.stop - r.start for r in self._rows}) == 1
        self._drawing = [True] * len(self.blocks)
        self._defer: Callable[[torch.Tensor, Callable[[torch.Tensor], torch.Tensor]],
                              torch.Tensor] | None = None

    @contextlib.contextmanager
    def only_for(self, mask: torch.Tensor) -> Iterator[bool]:
        """Draws inside are for the envs in `mask`, and it says whether there are any: work
        for none (a reset, a resample) may be skipped. On the CPU, reading the mask is free, and
        the blocks with no env in it neither draw nor advance: what a block draws then depends
        on its own envs only, not on whether others, in its batch or not, are in the mask. On a
        GPU it says yes and every block draws: reading the mask would wait for the device and
        break the step's CUDA graph; nor when told not to read masks (a compiled step)."""
        if not self._reads_masks:
            yield True
            return
        if self._equal:  # one op, not a cumulative sum: this runs on most steps
            blocks = mask.view(len(self._rows), -1).any(dim=1).tolist()
        else:
            ended = mask.cumsum(0)[self._ends - 1]
            blocks = torch.diff(ended, prepend=ended.new_zeros(1)).gt(0).tolist()
        if not any(blocks):
            yield False
            return
        drawing, self._drawing = self._drawing, blocks
        try:
            yield True
        finally:
            self._drawing = drawing

    def manual_seed(self, seed: int) -> None:
        for block, generator in zip(self.blocks, self.generators, strict=True):
            generator.manual_seed(int(np.random.SeedSequence([seed, block]).generate_state(1)[0]))

    def rand(self, *shape: int, dtype: torch.dtype | None = None) -> torch.Tensor:
        """A new `[num_envs, *shape]` tensor of uniform samples in [0, 1)."""
        return self.uniform_(torch.empty(self.num_envs, *shape, dtype=dtype, device=self.device))

    def uniform_(self, out: torch.Tensor) -> torch.Tensor:
        """`out` (`[num_envs, ...]`) filled with uniform samples in [0, 1), in place."""
        return self._fill(out, torch.Tensor.uniform_)

    def normal_(self, out: torch.Tensor) -> torch.Tensor:
        """`out` (`[num_envs, ...]`) filled with standard normal samples, in place."""
        return self._fill(out, torch.Tensor.normal_)

    def _fill(self, out: torch.Tensor, draw) -> torch.Tensor:
        if self._defer is not None:
            return self._defer(out, functools.partial(self._draw_blocks, draw=draw))
        return self._draw_blocks(out, draw)

    def _draw_blocks(self, out: torch.Tensor, draw) -> torch.Tensor:
        for rows, generator, drawing in zip(self._rows, self.generators, self._drawing,
                                            strict=True):
            if drawing:
                draw(out[rows], generator=generator)
        return out

    @contextlib.contextmanager
    def deferred(self, defer: Callable[[torch.Tensor, Callable[[torch.Tensor], torch.Tensor]],
                                       torch.Tensor]) -> Iterator[None]:
        """Inside, each draw into `out` is `defer(out, fill)` instead, where `fill(tensor)`
        makes the draw into `tensor`: a compiled step draws outside its compiled code
        (`labcli.envs.compiled`)."""
        self._defer = defer
        try:
            yield
        finally:
            self._defer = None

    def get_state(self) -> torch.Tensor:
        """Every block's generator state, a row each."""
        return torch.stack([g.get_state() for g in self.generators])

    def set_state(self, state: torch.Tensor) -> None:
        """Every generator's state from `get_state`'s rows. One generator (a GPU env's) takes the
        first of several: a GPU env drew per block of envs in labs before 2026-12-01, and such a
        run resumes, the first block's generator drawing for all envs."""
        rows = state[:1] if len(self.generators) == 1 else state
        for row, generator in zip(rows, self.generators, strict=True):
            generator.set_state(row.clone())

    def check_state(self, state: object) -> None:
        """Raise ValueError or TypeError unless `state` is one `get_state` could have returned,
        or, for one generator, a state of several blocks (`set_state`)."""
        rows = len(self.generators)
        if not isinstance(state, torch.Tensor) or state.dim() != 2 \
                or not (len(state) == rows or rows == 1 < len(state)):
            shown = tuple(state.shape) if isinstance(state, torch.Tensor) else type(state).__name__
            raise ValueError(f"{shown}, not a row for each of {rows} blocks")
        scratch = torch.Generator(self.generators[0].device)
        for row in state:
            scratch.set_state(row.clone())
