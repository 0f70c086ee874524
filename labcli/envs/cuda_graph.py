"""The env step replayed as one CUDA graph.

On a GPU an eager env step is a few hundred small kernel launches, and their Python and launch
cost (1.5-2.3 ms on an H100) exceeds the GPU's own work up to tens of thousands of envs: the
step is host-bound. Captured once and replayed, the same step costs one graph launch, and the
GPU's work sets the pace. The step must then be free of host syncs and keep its tensors'
shapes, as a batched env step is.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch

from labcli.errors import LabError

# Eager calls before the capture: lazy set-up (cuBLAS handles, the allocator's pools, kernels
# loaded on first use) cannot happen inside a capture. Torch's own examples warm up three times.
WARMUP_CALLS = 3
# The flag a user sets to step eagerly instead (a TaskConfig field).
FLAG = "env.cuda_graph"


class GraphedStep:
    """`fn(actions)` on CUDA: eager for the first `WARMUP_CALLS` calls, then captured once and
    replayed. Each call returns fresh copies of the captured outputs, so that a caller may keep
    them (as a learner keeps `obs` beside `next_obs`) while the next replay overwrites the graph's
    own. Random draws from `generators` advance with every replay."""

    def __init__(self, fn: Callable[[torch.Tensor], Any], generators: Sequence[torch.Generator],
                 what: str):
        self._fn = fn
        self._generators = list(generators)
        self._what = what
        self._calls = 0
        self._graph: torch.cuda.CUDAGraph | None = None
        self._input: torch.Tensor | None = None
        self._output: Any = None

    def __call__(self, actions: torch.Tensor) -> Any:
        if self._graph is None:
            if self._calls < WARMUP_CALLS:
                self._calls += 1
                return self._fn(actions)
            self._capture(actions)
        self._input.copy_(actions)
        self._graph.replay()
        return _fresh(self._output, {})

    def close(self) -> None:
        """Release the graph and its memory pool."""
        self._graph = self._input = self._output = None

    def _capture(self, actions: torch.Tensor) -> None:
        # Not an inference tensor, even when captured under torch.inference_mode (RSL-RL's
        # rollout): a later step outside that mode copies its actions in.
        with torch.inference_mode(False):
            self._input = torch.empty(actions.shape, dtype=actions.dtype, device=actions.device)
        graph = torch.cuda.CUDAGraph()
        for generator in self._generators:
            graph.register_generator_state(generator)
        try:
            # Kernels are recorded, not run: the env's state is the same after a capture.
            # thread_local: other threads' CUDA calls (a logger, a data loader) go on meanwhile.
            with torch.cuda.graph(graph, capture_error_mode="thread_local"):
                self._output = self._fn(self._input)
        except RuntimeError as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise LabError(
                f"{self._what} could not be captured in a CUDA graph ({first}); a step that "
                "waits for the GPU (.item(), .cpu(), a Python `if` on a tensor) cannot be",
                f"keep such code out of the task's step, or --set {FLAG}=false to step "
                "eagerly (slower)") from exc
        self._graph = graph


def _fresh(value: Any, copies: dict[int, torch.Tensor]) -> Any:
    """`value` with every tensor cloned; a tensor found twice is cloned once, so outputs that
    were the same tensor stay the same tensor."""
    if isinstance(value, torch.Tensor):
        if id(value) not in copies:
            copies[id(value)] = value.clone()
        return copies[id(value)]
    if isinstance(value, dict):
        return {k: _fresh(v, copies) for k, v in value.items()}
    if isinstance(value, tuple):
        return tuple(_fresh(v, copies) for v in value)
    return value
