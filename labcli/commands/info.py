"""`lab info`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from labcli import __version__
from labcli.commands.common import complete_task, out, table
from labcli.errors import LabError


def info(
    task: Annotated[str | None, typer.Option(
        "--task", "-t", help="Also say which model a task uses (a MuJoCo Menagerie robot: its "
                             "entry, version and files; nothing is downloaded).",
        autocompletion=complete_task)] = None,
    run: Annotated[Path | None, typer.Option(
        "--run", help="Also say which model a run recorded, which play, export and resume "
                      "use.")] = None,
) -> None:
    """Print versions of lab, MuJoCo, torch and the frameworks, the GL backend, and whether
    rendering, CUDA and MuJoCo Warp work here; with --task or --run, which model it uses.

    Example: lab info
    Example: lab info --task go1-flat
    """
    if task is not None and run is not None:
        raise LabError("--task and --run both name a model", "pass one of them")
    from labcli.runs import info as infos

    model = infos.model(task, run)  # a task or run that is wrong fails before the probes
    rows = table("", "", title=f"lab {__version__}")
    for name, value in infos.collect().items():
        rows.add_row(name, value)
    if model:
        rows.add_section()
    for name, value in model.items():
        rows.add_row(name, value)
    out().print(rows)
