"""A learning library's PPO update replayed as one CUDA graph, and its Adam fused, for framework
plugins.

The libraries' updates are launch-bound at lab's scale: each mini-batch step is a few hundred
small kernels and a few host syncs (loss reads, the adaptive learning rate's KL test), ~6 ms on
an H100 whatever the batch size. A plugin writes its library's mini-batch steps without host
syncs (the learning rate a device tensor that Adam reads, the losses summed on the device) and
`UpdateGraph` captures them once and replays them each iteration: one sync an update. In a
data-parallel run the steps average their gradients and the KL over the ranks with
`average_over_ranks`, NCCL collectives that the graph captures with the rest.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import torch
import torch.distributed as dist
from torch import nn

Key = tuple[nn.Module, str]


def adapt_adam(optimizer: torch.optim.Optimizer, lr: torch.Tensor | None = None) -> None:
    """The library's Adam, changed in place to step all parameters in one fused kernel (on the
    CPU its per-parameter loop was ~1 ms of RSL-RL's ~5 ms cartpole mini-batch step); given
    `lr`, a device tensor, also to read its learning rate from there (set to the optimizer's
    own) and to be capturable, for `UpdateGraph`. Again after `load_state_dict`, which brings
    back the saved, eager settings."""
    for group in optimizer.param_groups:
        group.update(fused=True, foreach=None)
    if lr is None:
        return
    lr.fill_(float(optimizer.param_groups[0]["lr"]))
    for group in optimizer.param_groups:
        group.update(lr=lr, capturable=True)
    for entry in optimizer.state.values():
        if "step" in entry:
            entry["step"] = entry["step"].to(lr.device, torch.float32)


def eager_adam_state(state: dict[str, Any]) -> dict[str, Any]:
    """An `adapt_adam`'s state dict as an eager Adam's, so that a checkpoint resumes on any
    device and with the library's own update."""
    groups = [{**group, "lr": float(group["lr"]), "capturable": False, "fused": None}
              for group in state["param_groups"]]
    # state_dict() hands out the live per-parameter dicts: copied, not changed.
    entries = {i: {**entry, "step": entry["step"].to("cpu", torch.float32)}
               for i, entry in state["state"].items()}
    return {**state, "param_groups": groups, "state": entries}


def average_over_ranks(tensors: Sequence[torch.Tensor]) -> None:
    """`tensors` (a mini-batch's gradients, a KL) averaged over the ranks of a data-parallel
    run, in place and in one collective: the sum over the ranks, divided by their number, as the
    libraries' own reductions compute it. No host sync, so that `UpdateGraph` captures it; on
    every rank the same result, so the ranks' agents stay equal."""
    flat = torch.cat([t.reshape(-1) for t in tensors])
    dist.all_reduce(flat)
    flat /= dist.get_world_size()
    for tensor, part in zip(tensors, flat.split([t.numel() for t in tensors]), strict=True):
        tensor.copy_(part.view_as(tensor))


_live: weakref.WeakSet[UpdateGraph] = weakref.WeakSet()


def release_graphs() -> None:
    """Free every captured update graph of this process (a later `replay` captures again).
    NCCL keeps a communicator whose collectives a graph holds until the graph is freed, and
    `destroy_process_group` waits for it: on two H100s it hung there, after training."""
    for graph in list(_live):
        graph.release()


class UpdateGraph:
    """`steps` (every mini-batch step of one update, without host syncs) captured on the first
    `replay` and replayed from then on.

    The graph reads and writes fixed tensors, but libraries rebind module buffers to new tensors
    (RSL-RL's normalizer its std after each update, skrl's running scaler its statistics in the
    update's first epoch). So before a replay, buffers rebound since are copied to where the
    graph reads them; after it, buffers the graph rebinds are copied back there; and those
    tensors stay the modules' buffers.
    """

    def __init__(self, steps: Callable[[], None], optimizer: torch.optim.Optimizer,
                 modules: Iterable[nn.Module], state: Iterable[torch.Tensor] = ()):
        self.steps, self.optimizer = steps, optimizer
        self.modules = [m for module in modules for m in module.modules()]
        self.state = list(state)  # device tensors `steps` changes besides the above
        self._graph: torch.cuda.CUDAGraph | None = None
        self._reads: dict[Key, torch.Tensor] = {}
        self._writes: dict[Key, torch.Tensor] = {}
        _live.add(self)

    def release(self) -> None:
        if self._graph is not None:
            self._graph.reset()
            self._graph = None

    def replay(self) -> None:
        if self._graph is None:
            self._capture()
        self._bind(self._current(), self._reads)
        self._graph.replay()
        self._bind(self._writes, self._reads)

    def _current(self) -> dict[Key, torch.Tensor]:
        return {(m, name): b for m in self.modules for name, b in m._buffers.items()
                if b is not None}

    @staticmethod
    def _bind(source: dict[Key, torch.Tensor], target: dict[Key, torch.Tensor]) -> None:
        with torch.no_grad():
            for (module, name), tensor in target.items():
                if source[module, name] is not tensor:
                    tensor.copy_(source[module, name])
                module._buffers[name] = tensor

    def _capture(self) -> None:
        # A warm-up outside the graph creates what the capture needs (Adam's moments, the
        # gradients, library workspaces); then everything it changed is put back, so that the
        # first replay is the update the library would do.
        opt = self.optimizer
        params = [p for group in opt.param_groups for p in group["params"]]
        before = [p.detach().clone() for p in params]
        moments = {p: {k: v.clone() for k, v in s.items()} for p, s in opt.state.items()}
        state = [t.clone() for t in self.state]
        self._reads = self._current()
        buffers = {key: b.clone() for key, b in self._reads.items()}
        device = params[0].device
        side = torch.cuda.Stream(device)
        side.wait_stream(torch.cuda.current_stream(device))
        with torch.cuda.stream(side):
            self.steps()
        torch.cuda.current_stream(device).wait_stream(side)
        self._bind(buffers, self._reads)
        self._graph = torch.cuda.CUDAGraph()
        # Captured on the warm-up's stream: the libraries keep the last step's autograd graph
        # (their distributions hold it), and gradient nodes made on another stream would
        # synchronize inside the capture.
        # Thread-local: NCCL's watchdog thread queries the events of earlier collectives while
        # this thread captures, which a global capture would count as an error.
        with torch.cuda.graph(self._graph, stream=side, capture_error_mode="thread_local"):
            self.steps()
        self._writes = self._current()
        with torch.no_grad():
            for p, value in zip(params, before, strict=True):
                p.copy_(value)
            for p, s in opt.state.items():
                for key, value in s.items():
                    value.copy_(moments[p][key]) if p in moments else value.zero_()
            for tensor, value in zip(self.state, state, strict=True):
                tensor.copy_(value)
        self._bind(self._reads, self._reads)
