"""Tensors in shared memory, for the cpu backend's env shards. On Linux that is /dev/shm, a
tmpfs that containers often keep small (Docker's default is 64 MiB): torch's error there becomes
one line that says how full it is and what to change."""

from __future__ import annotations

import shutil
from pathlib import Path

import torch

from labcli.errors import LabError

SHM = Path("/dev/shm")


def shared(tensor: torch.Tensor) -> torch.Tensor:
    """`tensor`, moved into shared memory (as `share_memory_`)."""
    try:
        return tensor.share_memory_()
    except RuntimeError as exc:
        if "shared memory" not in str(exc):
            raise
        raise LabError(f"the env shards' tensors do not fit in shared memory{_room()}",
                       "give /dev/shm more room (docker run --shm-size=1g), use fewer envs, or "
                       "--set env.threads=1 to step them in one process") from None


def _room() -> str:
    """How full /dev/shm is, where there is one (torch's own message says little: "No space left
    on device" from one version, "Success" from another)."""
    if not SHM.is_dir():
        return ""
    usage = shutil.disk_usage(SHM)
    return f" (/dev/shm: {usage.free / 2**20:.1f} MiB free of {usage.total / 2**20:.0f} MiB)"
