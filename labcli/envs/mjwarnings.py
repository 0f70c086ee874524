"""MuJoCo's warnings during training: counted, not printed.

MuJoCo prints each warning to stderr and appends it to ./MUJOCO_LOG.TXT: thousands of lines, in
whatever directory `lab` runs from, once envs diverge every step. lab already resets and counts
diverged envs (`sim/instabilities`); while training, the warnings are counted for TensorBoard
(`sim/mujoco_warnings`) and the first one is kept to be shown once.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

import mujoco


class WarningCounter:
    def __init__(self) -> None:
        self._lock = threading.Lock()  # MuJoCo calls back from its rollout threads
        self._count = 0
        self.first: str | None = None

    def __call__(self, message: str) -> None:
        with self._lock:
            self._count += 1
            if self.first is None:
                self.first = message.strip()

    def pop(self) -> int:
        """Warnings since the last call."""
        with self._lock:
            count, self._count = self._count, 0
        return count


@contextmanager
def counted(counter: WarningCounter) -> Iterator[WarningCounter]:
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(counter)
    try:
        yield counter
    finally:
        mujoco.set_mju_user_warning(previous)
