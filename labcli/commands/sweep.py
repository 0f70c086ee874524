"""`lab sweep`."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from labcli.commands.common import (
    LogsDir,
    SetOpt,
    complete_framework,
    complete_task,
    err,
    out,
    say,
    table,
)
from labcli.errors import LabError

if TYPE_CHECKING:
    from labcli.runs.sweep import SweepOutcome


def sweep(
    task: Annotated[str | None, typer.Option(
        "--task", "-t", help="Task, see `lab list`.", autocompletion=complete_task)] = None,
    framework: Annotated[str | None, typer.Option(
        "--framework", "-f", help="Learning library.", autocompletion=complete_framework)
    ] = None,
    space_file: Annotated[Path | None, typer.Option(
        "--space", help="YAML mapping env.*/agent.* keys to one distribution each: "
        "{loguniform: [a, b]}, {uniform: [a, b]}, {randint: [a, b]}, {choice: [...]}.")] = None,
    samples: Annotated[int | None, typer.Option(help="Trials to run.")] = None,
    metric: Annotated[str, typer.Option(
        help="What ranks the trials: success (Metrics/success_rate) or return "
        "(Train/mean_reward), the higher the better.")] = "success",
    scheduler: Annotated[str, typer.Option(
        help="asha: stop the worst trials early (ASHA); none: run every trial to the end.")
    ] = "asha",
    max_concurrent: Annotated[int | None, typer.Option(
        help="Trials at a time [CPU: the cores over a trial's threads, 1 each; GPU: one a "
        "GPU].")] = None,
    address: Annotated[str | None, typer.Option(
        help="Join this Ray cluster (ray://HOST:10001, HOST:6379) [a local Ray].")] = None,
    set_: SetOpt = None,
    iterations: Annotated[int | None, typer.Option(
        help="Each trial's iterations [the framework's default].")] = None,
    name: Annotated[str | None, typer.Option(
        help="The sweep's folder under <logs>/sweeps/ [the time].")] = None,
    search: Annotated[str, typer.Option(
        help="random, or optuna (Optuna's TPE, told each finished trial).")] = "random",
    resume: Annotated[Path | None, typer.Option(
        help="Continue an interrupted sweep: its folder, <logs>/sweeps/<name>.")] = None,
    logs_dir: LogsDir = None,
) -> None:
    """Sweep hyperparameters with Ray Tune: each trial a lab run, the best as a config file.

    Results go to <logs>/sweeps/<name>/ (results.json, best.yaml, Ray's state); trials are runs
    under <logs>/<framework>/<task>/. Ctrl-C stops the sweep, its trials checkpointed; --resume
    continues it. Needs Ray: pip install "lab[sweep]".

    Example: lab sweep --task cartpole --framework rsl_rl --space space.yaml --samples 16
    """
    from labcli.runs import sweep as sweeps

    if resume is not None:
        given = [option for option, value in (
            ("--task", task), ("--framework", framework), ("--space", space_file),
            ("--samples", samples), ("--set", set_), ("--iterations", iterations),
            ("--name", name), ("--max-concurrent", max_concurrent),
            ("--logs-dir", logs_dir)) if value]
        given += [option for option, value, default in (
            ("--metric", metric, "success"), ("--scheduler", scheduler, "asha"),
            ("--search", search, "random")) if value != default]
        if given:
            raise LabError(f"--resume continues {resume} as it was started, so {given[0]} "
                           "cannot be given with it", f"drop {', '.join(given)}")
        outcome = sweeps.resume(resume, address=address, console=err())
    else:
        missing = [option for option, value in (("--task", task), ("--framework", framework),
                                                ("--space", space_file),
                                                ("--samples", samples)) if value is None]
        if missing:
            raise LabError(f"lab sweep needs {', '.join(missing)}",
                           "e.g. lab sweep --task cartpole --framework rsl_rl --space "
                           "space.yaml --samples 16; or --resume DIR")
        outcome = sweeps.sweep(
            task, framework, space_file, samples=samples, metric=metric, scheduler=scheduler,
            search=search, max_concurrent=max_concurrent, address=address,
            overrides=set_ or [], iterations=iterations, name=name, logs_dir=logs_dir,
            console=err())
    _print(outcome)
    if outcome.interrupted:
        say(f"interrupted: continue with lab sweep --resume {outcome.dir}")
        raise typer.Exit(128 + int(outcome.signum))
    failed = [row for row in outcome.rows if row.state == "failed"]
    if outcome.rows and len(failed) == len(outcome.rows):
        raise LabError(f"every trial failed; the first: {failed[0].error or 'see its run'}")


def _print(outcome: SweepOutcome) -> None:
    from rich.table import Column

    from labcli.runs import sweep as sweeps

    spec = outcome.spec
    keys = list(spec.space)
    runs = Path(spec.logs_dir) / spec.framework / spec.task
    # The sweep's metric, then the other figure, which breaks its ties.
    figures = [spec.metric, *(name for name in sweeps.METRICS if name != spec.metric)]
    shown = table("trial", *keys, *figures, "iterations", Column("state", no_wrap=True),
                  f"run in {runs}", title=f"{len(outcome.rows)} trials of sweep {spec.name}, "
                  f"best {spec.metric} first")
    for row in outcome.rows:
        shown.add_row(row.trial_id, *(_value(row.params.get(key)) for key in keys),
                      *(sweeps.format_metric(name, row.figures.get(name)) for name in figures),
                      "-" if row.iterations is None else f"{row.iterations}/{spec.iterations}",
                      row.state, row.run_dir.name if row.run_dir else "-")
    out().print(shown)
    for row in outcome.rows:
        if row.error:
            err().print(f"note: trial {row.trial_id} failed: {row.error}", highlight=False,
                        soft_wrap=True)
    for note in outcome.notes:
        err().print(f"note: {note}", highlight=False, soft_wrap=True)
    say(f"results: {outcome.dir / 'results.json'}")
    if outcome.best_file is not None:
        say(f"best: {outcome.best_file} (lab train --task {spec.task} --framework "
            f"{spec.framework} --config {outcome.best_file})")


def _value(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return "-" if value is None else str(value)
