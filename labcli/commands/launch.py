"""The `lab` console script. SIGINT/SIGTERM are recorded from its first line until a command
starts (labcli/runs/interrupt.py): a signal while `lab` imports and parses ends it with one line
and exit code 130/143 instead of a traceback from inside an import. Each command then handles
signals its own way (labcli/commands/app.py)."""

from __future__ import annotations

import sys

from labcli.runs import interrupt


def _interrupted(stop: interrupt.StopRequest) -> None:
    print(f"interrupted by {stop.name} during start-up; nothing was written", file=sys.stderr)
    sys.exit(stop.exit_code)


def main() -> None:
    with interrupt.deferred(interrupt.startup) as stop:
        from labcli.commands.app import main as cli_main

        if stop.requested:
            _interrupted(stop)
        cli_main()
