"""Tensors in shared memory, for the cpu backend's env shards. On Linux that is /dev/shm, a
tmpfs that containers often keep small (Docker's default is 64 MiB): torch then fails with "No
space left on device", which becomes one line that says what to change."""

from __future__ import annotations

import torch

from labcli.errors import LabError, first_line


def shared(tensor: torch.Tensor) -> torch.Tensor:
    """`tensor`, moved into shared memory (as `share_memory_`)."""
    try:
        return tensor.share_memory_()
    except RuntimeError as exc:
        if "shared memory" not in str(exc):
            raise
        raise LabError("the env shards' tensors do not fit in shared memory (/dev/shm: "
                       f"{first_line(exc).rsplit(': ', 1)[-1]})",
                       "give /dev/shm more room (docker run --shm-size=1g), use fewer envs, or "
                       "--set env.threads=2 to step them in one process") from None
