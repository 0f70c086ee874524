"""`lab plot`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from labcli.commands.common import FrameworkOpt, LogsDir, TaskOpt, err, say


def plot(
    run_dirs: Annotated[list[Path] | None, typer.Argument(
        help="Run directories [the newest run, or --last N]", show_default=False)] = None,
    metric: Annotated[str | None, typer.Option(
        help="TensorBoard tag to plot [the mean episode return, Train/mean_reward].",
        show_default=False)] = None,
    output: Annotated[Path, typer.Option("--output", "-o", help="PNG file to write.")] =
        Path("plot.png"),
    last: Annotated[int, typer.Option(help="Without RUN: the N newest runs.")] = 1,
    task: TaskOpt = None,
    framework: FrameworkOpt = None,
    logs_dir: LogsDir = None,
) -> None:
    """Draw learning curves (a metric against env steps) of one or more runs into a PNG.

    Example: lab plot --task cartpole --last 3 -o cartpole.png
    """
    from labcli.runs import plot as plots

    metric = metric or plots.DEFAULT_METRIC
    selected = plots.select(run_dirs or [], logs_dir=logs_dir, last=last, task=task,
                            framework=framework)
    result = plots.plot(selected, output, metric)
    for run in result.skipped:
        err().print(f"note: {run.dir} has no '{metric}' yet; left out", highlight=False)
    say(f"wrote {result.path}: {metric} of {len(result.plotted)} run(s)")
