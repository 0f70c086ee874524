"""The `lab` command: a thin layer that parses, calls one library function and prints."""

from __future__ import annotations

import functools
import json
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table, box

from labcli import __version__, bench, export, play, plugins, training
from labcli.errors import LabError

app = typer.Typer(
    help="Train, play and export RL policies for MuJoCo robots with SB3, RSL-RL or skrl.",
    no_args_is_help=True, add_completion=True, pretty_exceptions_enable=False,
)
out = Console()
err = Console(stderr=True)

LogsDir = Annotated[Path | None, typer.Option(
    "--logs-dir", help="Where runs live [default: ./logs or $LAB_LOGS_DIR].")]
TaskOpt = Annotated[str | None, typer.Option("--task", "-t", help="Filter runs by task.")]
FrameworkOpt = Annotated[str | None, typer.Option("--framework", "-f",
                                                  help="Filter runs by framework.")]
RunOpt = Annotated[Path | None, typer.Option("--run", help="A run directory.")]


def command(*args: Any, **kwargs: Any) -> Callable:
    """app.command that turns a LabError into one line on stderr and exit code 2."""

    def wrap(fn: Callable) -> Callable:
        @functools.wraps(fn)
        def run(*a: Any, **kw: Any) -> Any:
            try:
                return fn(*a, **kw)
            except LabError as exc:
                err.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
                raise typer.Exit(exc.exit_code) from None

        return app.command(*args, **kwargs)(run)

    return wrap


def _table(*columns: str, title: str | None = None) -> Table:
    table = Table(*columns, title=title, box=box.SIMPLE_HEAD if out.is_terminal else None,
                  title_justify="left")
    return table


def _version(value: bool) -> None:
    if value:
        out.print(f"lab {__version__}")
        raise typer.Exit()


@app.callback()
def main_callback(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True,
                                          help="Print the version and exit.")] = False,
) -> None:
    """Train, play and export RL policies for MuJoCo robots with SB3, RSL-RL or skrl."""


@command("list")
def list_command() -> None:
    """List tasks, frameworks and wrappers, with the package that provides each.

    Example: lab list
    """
    reg = plugins.registry()
    for kind, title in (("task", "Tasks"), ("framework", "Frameworks"), ("wrapper", "Wrappers")):
        table = _table("name", "description", "provided by", title=title)
        for name in reg.names(kind):
            item, provider = reg.items[kind][name]
            table.add_row(name, getattr(item, "description", ""), str(provider))
        out.print(table)
    if reg.failures:
        table = _table("plugin", "package", "error", title="Plugins that failed to load")
        for failure in reg.failures:
            table.add_row(failure.plugin, str(failure.provider), failure.error)
        out.print(table)


@command()
def train(
    task: Annotated[str, typer.Option("--task", "-t", help="Task to train, see `lab list`.")],
    framework: Annotated[str, typer.Option("--framework", "-f", help="Learning library.")],
    num_envs: Annotated[int | None, typer.Option(help="Parallel envs [task default].")] = None,
    seed: Annotated[int | None, typer.Option(
        help="Seeds the env, torch, NumPy and the framework [0; a resumed run keeps its own].")
    ] = None,
    max_iterations: Annotated[int | None, typer.Option(
        help="Rollout + update cycles [framework default].")] = None,
    device: Annotated[str, typer.Option(help="Torch device for the learner.")] = "cpu",
    backend: Annotated[str | None, typer.Option(
        help="Simulation backend: cpu, or warp (GPU) [warp where CUDA is available].")] = None,
    run_name: Annotated[str | None, typer.Option(help="Suffix of the run directory.")] = None,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", help="Override a setting: env.KEY=VALUE or agent.KEY=VALUE (repeatable).")] = None,
    config_file: Annotated[Path | None, typer.Option(
        "--config", help="YAML file with 'env:' and 'agent:' settings.")] = None,
    checkpoint: Annotated[str | None, typer.Option(
        help="Resume from a checkpoint file, a run dir, or 'latest'.")] = None,
    logs_dir: LogsDir = None,
) -> None:
    """Train a policy; the run goes to logs/<framework>/<task>/<time>/.

    Example: lab train --task cartpole --framework sb3 --set agent.learning_rate=1e-3
    """
    outcome = training.train(
        task, framework, num_envs=num_envs, seed=seed, max_iterations=max_iterations,
        device=device, backend=backend, run_name=run_name, overrides=set_ or [],
        config_file=config_file, checkpoint=checkpoint, logs_dir=logs_dir, console=err)
    s = outcome.summary
    figures = [f"{s['state']}", f"{s['iterations']} iterations", f"{s['steps']:,} steps",
               f"{s['wall_time_s']:.1f} s"]
    if s["mean_return"] is not None:
        figures.append(f"mean return {s['mean_return']:.1f}")
    if s["success_rate"] is not None:
        figures.append(f"success {s['success_rate']:.0%}")
    out.print(f"{outcome.run.dir}: " + ", ".join(figures), highlight=False, soft_wrap=True)
    if s["state"] == "interrupted":
        raise typer.Exit(128 + int(s.get("signal", signal.SIGINT)))


@command("play")
def play_command(
    last: Annotated[bool, typer.Option("--last", help="Newest run (the default).")] = True,
    run: RunOpt = None,
    checkpoint: Annotated[Path | None, typer.Option(help="A checkpoint file.")] = None,
    task: TaskOpt = None,
    framework: FrameworkOpt = None,
    num_envs: Annotated[int | None, typer.Option(help="Parallel envs [episodes, max 256].")] = None,
    episodes: Annotated[int, typer.Option(help="Episodes to roll out.")] = 10,
    seed: Annotated[int, typer.Option(help="Seed of the evaluation episodes.")] = 0,
    logs_dir: LogsDir = None,
) -> None:
    """Roll out a trained policy deterministically; print episode returns and success rate.

    Example: lab play --last --framework sb3 --episodes 100
    """
    loaded, eps = play.play(episodes=episodes, seed=seed, run_dir=run, checkpoint=checkpoint,
                            task=task, framework=framework, num_envs=num_envs, logs_dir=logs_dir)
    table = _table("episode", "return", "length", "ended by", "success",
                   title=f"{loaded.run.dir} · {loaded.checkpoint.path.name}")
    for i, (r, n, cause, ok) in enumerate(zip(eps.returns, eps.lengths, eps.causes,
                                              eps.successes, strict=True)):
        table.add_row(str(i), f"{r:.1f}", str(n), cause, "yes" if ok else "no")
    out.print(table)
    out.print(f"{len(eps.returns)} episodes: mean return {eps.mean_return:.1f}, "
              f"success rate {eps.success_rate:.0%}", highlight=False)


@command("export")
def export_command(
    fmt: Annotated[export.Format, typer.Argument(help="onnx or jit (TorchScript).")],
    last: Annotated[bool, typer.Option("--last", help="Newest run (the default).")] = True,
    run: RunOpt = None,
    checkpoint: Annotated[Path | None, typer.Option(help="A checkpoint file.")] = None,
    task: TaskOpt = None,
    framework: FrameworkOpt = None,
    logs_dir: LogsDir = None,
) -> None:
    """Export a policy (normalizer folded in) to <run>/exported/ and check it against torch.

    Example: lab export onnx --last
    """
    result = export.export(fmt, run_dir=run, checkpoint=checkpoint, task=task,
                           framework=framework, logs_dir=logs_dir)
    out.print(f"wrote {result.path} and {result.metadata.name}; max abs difference from torch "
              f"{result.max_abs_diff:.2e} over {result.checked} observations", highlight=False,
              soft_wrap=True)


@command("bench")
def bench_command(
    task: Annotated[str, typer.Option("--task", "-t", help="Task to measure, see `lab list`.")],
    num_envs: Annotated[str, typer.Option(help="Comma-separated env counts.")] = "16,256,1024",
    backend: Annotated[str | None, typer.Option(
        help="Simulation backend: cpu or warp [warp where CUDA is available].")] = None,
    device: Annotated[str, typer.Option(help="Torch device of the env.")] = "cpu",
    framework: Annotated[str | None, typer.Option(
        "--framework", "-f", help="Also time a short training run with this framework.")] = None,
    seconds: Annotated[float, typer.Option(help="Seconds per measurement.")] = 3.0,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """Measure env-steps/s of a task (random actions, resets included) and, with --framework,
    training steps/s.

    Example: lab bench --task cartpole --num-envs 16,256,1024 --framework rsl_rl
    """
    try:
        counts = [int(n) for n in num_envs.split(",")]
    except ValueError:
        raise LabError(f"--num-envs '{num_envs}' is not a list of integers",
                       "e.g. --num-envs 16,256,1024") from None
    rows = bench.bench(task, counts, backend=backend, device=device, framework=framework,
                       seconds=seconds)
    if as_json:
        out.print_json(json.dumps([row.as_dict() for row in rows]))
        return
    columns = ["task", "backend", "envs", "env-steps/s"]
    if framework:
        columns += ["framework", "training steps/s"]
    table = _table(*columns, title="lab bench")
    for row in rows:
        cells = [row.task, row.backend, str(row.num_envs), f"{row.env_steps_per_s:,.0f}"]
        if framework:
            cells += [row.framework, f"{row.train_steps_per_s:,.0f}"]
        table.add_row(*cells)
    out.print(table)


def main() -> None:
    app()
