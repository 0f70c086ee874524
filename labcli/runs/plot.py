"""`lab plot`: learning curves of one or more runs from their TensorBoard event files."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from labcli import files
from labcli.envs import metrics
from labcli.errors import LabError
from labcli.runs import rundir

DEFAULT_METRIC = metrics.MEAN_RETURN


def read_scalars(run_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """Every TensorBoard scalar in `run_dir` as (step, value) pairs sorted by step, by tag."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(run_dir.glob("events.out.tfevents.*")):
        # TensorBoard's reader opens whatever the name is: a directory fails inside it, a FIFO
        # would block it.
        if not files.is_regular(path):
            raise LabError(f"{path} is not a regular file: lab reads a run's TensorBoard "
                           "events from regular files", "remove it, or plot another run")
        acc = EventAccumulator(str(path), size_guidance={"scalars": 0})
        acc.Reload()
        for tag in acc.Tags()["scalars"]:
            out.setdefault(tag, []).extend((e.step, e.value) for e in acc.Scalars(tag))
    return {tag: sorted(points) for tag, points in out.items()}


def select(paths: Sequence[Path] = (), *, logs_dir: Path | None = None, last: int = 1,
           task: str | None = None, framework: str | None = None) -> list[rundir.Run]:
    """The runs named by `paths`, or else the `last` newest runs matching the filters."""
    if paths:
        return [rundir.open_run(path) for path in paths]
    if last <= 0:
        raise LabError(f"--last must be a positive number of runs, got {last}")
    logs_dir = logs_dir or rundir.default_logs_dir()
    found = rundir.find(logs_dir, task, framework)
    if not found:
        rundir.latest(logs_dir, task, framework)  # raises the usual "no runs found"
    return found[:last]


@dataclass
class PlotResult:
    path: Path
    plotted: list[rundir.Run] = field(default_factory=list)
    skipped: list[rundir.Run] = field(default_factory=list)  # runs that never logged the metric


def plot(selected: Sequence[rundir.Run], output: Path,
         metric: str = DEFAULT_METRIC) -> PlotResult:
    """One curve per run of `metric` against env steps, saved as a PNG (Agg, no display)."""
    if output.suffix.lower() != ".png":
        raise LabError(f"-o {output}: lab writes PNG images", "name a file ending in .png")
    curves = {}
    available: set[str] = set()
    for run in selected:
        scalars = read_scalars(run.dir)
        available.update(scalars)
        if metric in scalars:
            curves[run.dir] = scalars[metric]
    if not curves:
        tags = ", ".join(sorted(available)) or "none (no TensorBoard event files)"
        raise LabError(f"no selected run logged metric '{metric}'", f"available tags: {tags}")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    result = PlotResult(output)
    for run in selected:
        if run.dir not in curves:
            result.skipped.append(run)
            continue
        steps, values = zip(*curves[run.dir], strict=True)
        ax.plot(steps, values, label=_label(run))
        result.plotted.append(run)
    ax.set_xlabel("env steps")
    ax.set_ylabel(metric)
    ax.set_title(metric)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    fig.tight_layout()
    with files.staged(output) as tmp:  # -o names a place of the user's, links and all
        fig.savefig(tmp, format="png")
    return result


def _label(run: rundir.Run) -> str:
    manifest = run.manifest()
    return f"{manifest.get('framework', '?')} · {manifest.get('task', '?')} · {run.name}"
