"""What every command shares: the two consoles, the options several commands take, shell
completion of task and framework names, and table helpers."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from rich.console import Console
    from rich.table import Column, Table


PIPED_WIDTH = 1000  # columns of stdout when it is not a terminal and $COLUMNS is not set

# Consoles are made where they print: completion, --help and --version print through typer and
# need no rich, and each console reads the terminal's width then. No markup: what lab prints
# quotes run dirs, paths and user input, in which rich would take '[...]' for markup and drop it
# ('.[warp]', a run named 'a[bold]b').
def out() -> Console:
    from rich.console import Console

    console = Console(markup=False)
    if not console.is_terminal and "COLUMNS" not in os.environ:
        # Piped or redirected (`lab runs | grep finished`, `> runs.txt`), a table keeps every
        # cell whole: rich would fit it to 80 columns and cut names and paths short.
        console.width = PIPED_WIDTH
    return console


def err() -> Console:
    from rich.console import Console

    return Console(stderr=True, markup=False)


# Completion runs `lab` on every TAB: the registry (and gymnasium, after "gym:") load only then.
def complete_task(incomplete: str) -> list[str]:
    """Registered tasks; after "gym:", gymnasium's registered ids."""
    from labcli.envs import gym_spec
    from labcli.plugins import registry

    if gym_spec.is_gym_task(incomplete):
        names = gym_spec.gym_ids()
    else:
        names = [*registry.loaded().names(registry.TASK), gym_spec.PREFIX]
    return [name for name in names if name.startswith(incomplete)]


def complete_framework(incomplete: str) -> list[str]:
    from labcli.plugins import registry

    return [name for name in registry.loaded().names(registry.FRAMEWORK)
            if name.startswith(incomplete)]


LogsDir = Annotated[Path | None, typer.Option(
    "--logs-dir", help="Where runs live [default: ./logs or $LAB_LOGS_DIR].")]
TaskOpt = Annotated[str | None, typer.Option("--task", "-t", help="Filter runs by task.",
                                             autocompletion=complete_task)]
FrameworkOpt = Annotated[str | None, typer.Option("--framework", "-f",
                                                  help="Filter runs by framework.",
                                                  autocompletion=complete_framework)]
TaskArg = Annotated[str, typer.Option(
    "--task", "-t", help="Task, see `lab list`; or gym:<gymnasium id>.",
    autocompletion=complete_task)]
FrameworkArg = Annotated[str, typer.Option("--framework", "-f", help="Learning library.",
                                           autocompletion=complete_framework)]
RunOpt = Annotated[Path | None, typer.Option("--run", help="A run directory.")]
LastOpt = Annotated[bool, typer.Option("--last", help="Newest run (the default).")]
CheckpointOpt = Annotated[Path | None, typer.Option(
    help="A checkpoint file, or 'latest' or 'best' (the highest success, then return) of --run "
    "or of the newest run.")]
SetOpt = Annotated[list[str] | None, typer.Option(
    "--set", metavar="SECTION.KEY=VALUE",
    help="Override a setting: env.KEY=VALUE or agent.KEY=VALUE (repeatable).")]
# play and export of a trained run: only what the task lets play change, and the files its
# params name (which lab opens only when the user names them).
RunSetOpt = Annotated[list[str] | None, typer.Option(
    "--set", metavar="env.KEY=VALUE",
    help="Override an env setting of the run (repeatable): what its task lets play change, "
         "and a file its params name (env.kwargs.xml_file=...).")]
ConfigOpt = Annotated[Path | None, typer.Option(
    "--config", help="YAML file with 'env:' and 'agent:' settings (see `lab config show`).")]
VideoLengthOpt = Annotated[int, typer.Option(help="Env steps per video.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")]


def table(*columns: str | Column, title: str | None = None) -> Table:
    from rich.table import Table, box

    return Table(*columns, title=title, box=box.SIMPLE_HEAD if out().is_terminal else None,
                 title_justify="left")


def figure(value: float | None, fmt: str) -> str:
    return "-" if value is None else fmt.format(value)


def say(text: str) -> None:
    """A line of results on stdout, never wrapped or highlighted (it may quote paths)."""
    out().print(text, highlight=False, soft_wrap=True)
