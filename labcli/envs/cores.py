"""The cores this process may use, without torch or MuJoCo: the cpu backend sizes its physics
threads with it, data-parallel ranks share them out, and a sweep's driver (which imports
neither) gives them to Ray."""

from __future__ import annotations

import os


def cores() -> int:
    """Cores this process may run on: a taskset or cpuset narrows them below the machine's,
    and more threads than cores only queue for them."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1
