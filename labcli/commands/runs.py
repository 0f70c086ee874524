"""`lab runs`."""

from __future__ import annotations

import json
from typing import Annotated

import typer

from labcli.commands.common import (
    FrameworkOpt,
    JsonOpt,
    LogsDir,
    TaskOpt,
    err,
    figure,
    out,
    table,
)


def runs(
    task: TaskOpt = None,
    framework: FrameworkOpt = None,
    state: Annotated[str | None, typer.Option(
        help="Filter by state: finished, interrupted, failed, running or damaged.")] = None,
    as_json: JsonOpt = False,
    logs_dir: LogsDir = None,
) -> None:
    """List runs, newest first: task, framework, first start, steps, wall time over all
    sessions, final mean return, success rate, the best checkpoint's iteration and success (what
    `--checkpoint best` picks) and state ("failed": it stopped on an error or died
    without a summary; "damaged": its files cannot be read, and a note says why).

    Example: lab runs --task cartpole --state finished
    """
    from rich.table import Column

    from labcli.runs import checkpoints, rundir

    logs_dir = logs_dir or rundir.default_logs_dir()
    rows = rundir.table(logs_dir, task, framework, state)
    best = [checkpoints.best_recorded(row.dir) for row in rows]
    if as_json:
        out().print_json(json.dumps([
            {**row.as_dict(), "best_checkpoint": None if b is None else
             {"iteration": b[0], **b[1]}} for row, b in zip(rows, best, strict=True)]))
        return
    shown = table(Column("started", no_wrap=True), "task", "framework", "name", "steps",
                  "wall time", "return", "success", "best", Column("state", no_wrap=True),
                  title=f"{len(rows)} run{'' if len(rows) == 1 else 's'} in {logs_dir}")
    for row, b in zip(rows, best, strict=True):
        shown.add_row(
            row.started.replace("T", " ")[:16], row.task, row.framework,
            rundir.run_name(row.dir), figure(row.steps, "{:,}"),
            figure(row.wall_time_s, "{:.1f} s"), figure(row.mean_return, "{:.1f}"),
            figure(row.success_rate, "{:.0%}"),
            "-" if b is None else f"{b[0]}: {b[1][checkpoints.SUCCESS]:.0%}", row.state)
    out().print(shown)
    for row in rows:
        if row.problem:
            err().print(f"note: {row.problem}", highlight=False, soft_wrap=True)
