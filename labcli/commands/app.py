"""The `lab` command: a thin layer that parses, calls one library function and prints. Each
command lives in its own module; here they are put together, and a LabError raised anywhere
becomes one line on stderr and its exit code."""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from typing import Annotated, Any

import typer

from labcli import __version__
from labcli.commands import (
    bench,
    config,
    export,
    info,
    listing,
    play,
    plot,
    runs,
    sim2sim,
    sweep,
    train,
)
from labcli.commands.common import err
from labcli.errors import Interrupted, LabError, one_line
from labcli.runs import interrupt

SUMMARY = "Train, play and export RL policies for MuJoCo robots with SB3, RSL-RL or skrl."

app = typer.Typer(help=f"{SUMMARY}\n\nExample: lab train --task cartpole --framework sb3",
                  no_args_is_help=True, add_completion=True, pretty_exceptions_enable=False,
                  rich_markup_mode=None)
config_app = typer.Typer(
    help="Look at resolved configs.\n\nExample: lab config show --task cartpole --framework sb3",
    no_args_is_help=True, rich_markup_mode=None)
app.add_typer(config_app, name="config")


def one_line_errors(fn: Callable, *, saves: bool = False) -> Callable:
    """A LabError becomes one line on stderr and the error's exit code (2 for bad input). A
    signal from now on ends the command at once, one line, 130/143; a command that `saves`
    (training) keeps it recorded, and stops at its next step with a checkpoint."""

    @functools.wraps(fn)
    def run(*args: Any, **kwargs: Any) -> Any:
        try:
            if interrupt.startup.requested:
                raise Interrupted(f"interrupted by {interrupt.startup.name} during start-up; "
                                  "nothing was written", interrupt.startup.exit_code)
            if saves:
                return fn(*args, **kwargs)
            with interrupt.immediate():
                return fn(*args, **kwargs)
        except LabError as exc:
            from rich.text import Text

            from labcli.runs import ranks

            if getattr(exc, "said_by_launcher", False) and os.environ.get(ranks.LAUNCHED):
                raise typer.Exit(ranks.PEER_LOST_EXIT) from None
            err().print(Text.assemble(("error:", "bold red"), f" {one_line(str(exc))}"),
                        highlight=False, soft_wrap=True)
            raise typer.Exit(exc.exit_code) from None

    return run


for name, command in (("list", listing.list_), ("train", train.train), ("play", play.play),
                      ("export", export.export), ("sim2sim", sim2sim.sim2sim),
                      ("bench", bench.bench), ("runs", runs.runs),
                      ("plot", plot.plot), ("info", info.info), ("sweep", sweep.sweep)):
    # Training commands stop at a checkpoint on a signal, rather than at once.
    app.command(name)(one_line_errors(command, saves=command in (train.train, sweep.sweep)))
config_app.command("show")(one_line_errors(config.show))


def _version(value: bool) -> None:
    if value:
        typer.echo(f"lab {__version__}")
        raise typer.Exit()


@app.callback()
def main_callback(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True,
                                          help="Print the version and exit.")] = False,
) -> None:
    """Train, play and export RL policies for MuJoCo robots with SB3, RSL-RL or skrl."""


def main() -> None:
    app()
