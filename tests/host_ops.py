"""What a GPU step cannot hold, seen on the CPU: the ops torch's dispatcher runs that would copy
from the host or wait for the device there. A host read inside one aten kernel (a boolean index
counting its rows) does not go through the dispatcher and is not seen."""

from __future__ import annotations

import collections
import traceback
from pathlib import Path

import torch
from torch.utils._python_dispatch import TorchDispatchMode

aten = torch.ops.aten
CODE = [Path(__file__).resolve().parents[1] / part for part in ("labcli", "tasks", "plugins")]

# What a CUDA graph of the step cannot capture: a copy from the host, a wait for the device.
UNCAPTURABLE = {aten.lift_fresh.default: "a tensor made from host data",
                aten._local_scalar_dense.default: "a tensor read on the host"}
# What makes the host wait for a GPU: a read, a count of nonzero entries (its shape), and
# torch.normal's check that its std is not negative.
DEVICE_WAITS = {aten._local_scalar_dense.default: "a tensor read on the host",
                aten.nonzero.default: "a count of nonzero entries",
                **dict.fromkeys((aten.normal.Tensor_Tensor, aten.normal.Tensor_float,
                                 aten.normal.float_Tensor), "torch.normal's check of its std")}


class HostOps(TorchDispatchMode):
    """Inside, the ops of `ops` ({op: what it is}) that run are counted in `seen`, by the line
    of the project's code that ran each; with `raising`, the first raises a RuntimeError."""

    def __init__(self, ops: dict, raising: bool = False):
        super().__init__()
        self.ops, self.raising = ops, raising
        self.seen: collections.Counter[str] = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if func in self.ops:
            ours = [f for f in traceback.extract_stack()
                    if any(Path(f.filename).is_relative_to(code) for code in CODE)]
            where = f"{ours[-1].filename}:{ours[-1].lineno}" if ours else "outside lab"
            if self.raising:
                raise RuntimeError(f"{self.ops[func]} at {where}: on a GPU this would "
                                   "synchronize with the device")
            self.seen[f"{self.ops[func]} at {where}"] += 1
        return func(*args, **(kwargs or {}))
