"""The cores and memory this process may use, without torch or MuJoCo: the cpu backend sizes
its physics threads with them and refuses envs that cannot fit, data-parallel ranks share the
cores out, and a sweep's driver (which imports neither) gives them to Ray."""

from __future__ import annotations

import os
from pathlib import Path


def cores() -> int:
    """Cores this process may run on: a taskset or cpuset narrows them below the machine's,
    and more threads than cores only queue for them."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def available_memory() -> int | None:
    """Bytes of memory the host can still give (Linux's MemAvailable); None where unknown."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def gib(size: int) -> str:
    return f"{size / 2**30:,.1f} GiB" if size >= 2**30 else f"{size / 2**20:,.1f} MiB"
