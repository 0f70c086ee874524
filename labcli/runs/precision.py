"""The precision of float32 matrix products on CUDA while a run trains.

torch computes them in full float32 unless told otherwise; TF32 (a 10-bit mantissa in the
products, float32 sums) runs them on an Ampere or later GPU's tensor cores. mjlab trains in TF32
(`mjlab.utils.torch.configure_torch_backends`); lab does where `agent.tf32` says so. The
setting is torch's process-wide one, put back when the run ends: tests and sweeps train many
runs in one process.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch


@contextlib.contextmanager
def tf32(enabled: bool) -> Iterator[None]:
    """Within the block, CUDA's float32 matrix products and convolutions in TF32 where
    `enabled`, in full float32 where not; torch's settings as they were after it."""
    backends = torch.backends.cuda.matmul, torch.backends.cudnn
    if hasattr(backends[0], "fp32_precision"):  # torch 2.9 and later
        name, value = "fp32_precision", "tf32" if enabled else "ieee"
    else:
        name, value = "allow_tf32", enabled
    previous = [getattr(backend, name) for backend in backends]
    for backend in backends:
        setattr(backend, name, value)
    try:
        yield
    finally:
        for backend, setting in zip(backends, previous, strict=True):
            setattr(backend, name, setting)
