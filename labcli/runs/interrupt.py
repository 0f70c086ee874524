"""SIGINT and SIGTERM, handled from the first line `lab` runs: while it starts, recorded
(`startup`); during a command with nothing to save, the end of the process with one line and
128 + the signal's number (`immediate`); during training, a stop request that training honours at
its next step, rather than an exception raised wherever Python happens to be (mid-checkpoint,
inside a library's update) (`deferred`)."""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from labcli.errors import Interrupted

SIGNALS = (signal.SIGINT, signal.SIGTERM)


@dataclass
class StopRequest:
    """The first SIGINT/SIGTERM received while deferred; `signum` stays None until then."""

    signum: int | None = None
    repeats: int = 0  # signals after the first

    @property
    def requested(self) -> bool:
        return self.signum is not None

    def request(self, signum: int = signal.SIGINT) -> None:
        if self.signum is None:
            self.signum = signum

    @property
    def exit_code(self) -> int:
        """The shell's convention for a process ended by a signal: 130 for SIGINT, 143 for
        SIGTERM."""
        return 128 + int(self.signum or signal.SIGINT)

    @property
    def name(self) -> str:
        return signal.Signals(self.signum or signal.SIGINT).name


# A signal that arrives while `lab` starts, before a command runs: the console script records it
# here (labcli/commands/launch.py), and the command checks it first.
startup = StopRequest()


@contextmanager
def immediate() -> Iterator[None]:
    """Inside, SIGINT or SIGTERM ends the process at once with one line and the shell's exit
    code: for commands that write nothing, or write atomically (a temporary file is removed on
    the way out). Outside the main thread nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        print(f"interrupted by {signal.Signals(signum).name}", file=sys.stderr)
        raise SystemExit(128 + signum)

    previous = {s: signal.signal(s, handler) for s in SIGNALS}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@contextmanager
def deferred(stop: StopRequest | None = None) -> Iterator[StopRequest]:
    """Inside, the first SIGINT or SIGTERM only records itself in the returned StopRequest. A
    second one is acknowledged on one line, and changes nothing: an exception raised wherever
    Python is (mid-checkpoint, inside torch) would leave a traceback and half a save. A third
    ends the process at once (the way out of a stop that hangs), with the first signal's exit
    code and the last checkpoint written kept. The previous handlers come back on exit. Outside
    the main thread signals cannot be caught: nothing changes there."""
    stop = stop if stop is not None else StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return

    def handler(signum: int, frame: Any) -> None:
        if not stop.requested:
            stop.request(signum)
            return
        stop.repeats += 1
        name = signal.Signals(signum).name
        if stop.repeats == 1:
            print(f"{name} again: lab stops as soon as the last complete iteration is saved; "
                  f"once more ends it now", file=sys.stderr, flush=True)
            return
        print(f"{name}: ended now; the last checkpoint written is kept", file=sys.stderr,
              flush=True)
        os._exit(stop.exit_code)

    previous = {s: signal.signal(s, handler) for s in SIGNALS}
    try:
        yield stop
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def before_run(stop: StopRequest) -> Interrupted:
    """The error of a `lab train` stopped before its run dir existed."""
    return Interrupted(f"interrupted by {stop.name} before the run started; nothing was written",
                       stop.exit_code)
