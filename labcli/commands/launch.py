"""The `lab` console script. It catches SIGINT/SIGTERM before importing the CLI: a signal while
the commands are imported ends `lab` with one line and exit code 130/143 instead of a traceback
from inside an import. (torch and the learning libraries are imported later, by the commands that
need them, under their own handling.)"""

from __future__ import annotations

import sys

from labcli.runs import interrupt


def _interrupted(stop: interrupt.StopRequest) -> None:
    print(f"interrupted by {stop.name} during start-up; nothing was written", file=sys.stderr)
    sys.exit(stop.exit_code)


def main() -> None:
    with interrupt.deferred() as stop:
        try:
            from labcli.commands.app import main as cli_main
        except KeyboardInterrupt:  # a second signal while importing
            _interrupted(stop)
    if stop.requested:
        _interrupted(stop)
    cli_main()
