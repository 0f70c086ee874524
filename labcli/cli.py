"""The `lab` command: a thin layer that parses, calls one library function and prints."""

from __future__ import annotations

import functools
import json
import signal
from collections import Counter
from collections.abc import Callable
from importlib.metadata import version
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Column, Table, box
from rich.text import Text

from labcli import (
    __version__,
    bench,
    config,
    export,
    gym_bridge,
    info,
    play,
    plugins,
    runs,
    training,
)
from labcli import plot as plots
from labcli import video as videos
from labcli.errors import LabError
from labcli.video import VideoSettings

app = typer.Typer(
    help="Train, play and export RL policies for MuJoCo robots with SB3, RSL-RL or skrl.\n\n"
         "Example: lab train --task cartpole --framework sb3",
    no_args_is_help=True, add_completion=True, pretty_exceptions_enable=False,
)
config_app = typer.Typer(
    help="Look at resolved configs.\n\nExample: lab config show --task cartpole --framework sb3",
    no_args_is_help=True)
app.add_typer(config_app, name="config")
# No markup: what lab prints quotes run dirs, paths and user input, in which rich would take
# '[...]' for markup and drop it ('.[warp]', a run named 'a[bold]b').
out = Console(markup=False)
err = Console(stderr=True, markup=False)


def complete_task(incomplete: str) -> list[str]:
    """Registered tasks; after "gym:", gymnasium's registered ids."""
    if gym_bridge.is_gym_task(incomplete):
        names = gym_bridge.gym_ids()
    else:
        names = [*plugins.registry().names("task"), gym_bridge.PREFIX]
    return [name for name in names if name.startswith(incomplete)]


def complete_framework(incomplete: str) -> list[str]:
    return [name for name in plugins.registry().names("framework") if name.startswith(incomplete)]


LogsDir = Annotated[Path | None, typer.Option(
    "--logs-dir", help="Where runs live [default: ./logs or $LAB_LOGS_DIR].")]
TaskOpt = Annotated[str | None, typer.Option("--task", "-t", help="Filter runs by task.",
                                             autocompletion=complete_task)]
FrameworkOpt = Annotated[str | None, typer.Option("--framework", "-f",
                                                  help="Filter runs by framework.",
                                                  autocompletion=complete_framework)]
RunOpt = Annotated[Path | None, typer.Option("--run", help="A run directory.")]
SetOpt = Annotated[list[str] | None, typer.Option(
    "--set", help="Override a setting: env.KEY=VALUE or agent.KEY=VALUE (repeatable).")]
ConfigOpt = Annotated[Path | None, typer.Option(
    "--config", help="YAML file with 'env:' and 'agent:' settings (see `lab config show`).")]
VideoOpt = Annotated[bool, typer.Option("--video", help="Record env 0 as mp4.")]
VideoLengthOpt = Annotated[int, typer.Option(help="Env steps per video.")]


def command(*args: Any, group: typer.Typer = app, **kwargs: Any) -> Callable:
    """`group.command` that turns a LabError into one line on stderr and exit code 2."""

    def wrap(fn: Callable) -> Callable:
        @functools.wraps(fn)
        def run(*a: Any, **kw: Any) -> Any:
            try:
                return fn(*a, **kw)
            except LabError as exc:
                err.print(Text.assemble(("error:", "bold red"), f" {exc}"), highlight=False,
                          soft_wrap=True)
                raise typer.Exit(exc.exit_code) from None

        return group.command(*args, **kwargs)(run)

    return wrap


def _table(*columns: str | Column, title: str | None = None) -> Table:
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
        if kind == "task":
            table.add_row(f"{gym_bridge.PREFIX}<id>", gym_bridge.DESCRIPTION,
                          f"gymnasium {version('gymnasium')}")
        out.print(table)
    if reg.failures:
        table = _table("plugin", "package", "error", title="Plugins that failed to load")
        for failure in reg.failures:
            table.add_row(failure.plugin, str(failure.provider), failure.error)
        out.print(table)


@command()
def train(
    task: Annotated[str, typer.Option(
        "--task", "-t", help="Task to train, see `lab list`; or gym:<gymnasium id>.",
        autocompletion=complete_task)],
    framework: Annotated[str, typer.Option("--framework", "-f", help="Learning library.",
                                           autocompletion=complete_framework)],
    num_envs: Annotated[int | None, typer.Option(help="Parallel envs [task default].")] = None,
    seed: Annotated[int | None, typer.Option(
        help="Seeds the env, torch, NumPy and the framework [0; a resumed run keeps its own].")
    ] = None,
    max_iterations: Annotated[int | None, typer.Option(
        help="Rollout + update cycles [framework default].")] = None,
    device: Annotated[str | None, typer.Option(
        help="Torch device of the env and learner [cuda with the warp backend, else cpu].")] = None,
    backend: Annotated[str | None, typer.Option(
        help="Simulation backend: cpu, or warp (GPU) [warp where CUDA is available].")] = None,
    run_name: Annotated[str | None, typer.Option(help="Suffix of the run directory.")] = None,
    set_: SetOpt = None,
    config_file: ConfigOpt = None,
    checkpoint: Annotated[str | None, typer.Option(
        help="Resume from a checkpoint file, a run dir, or 'latest'.")] = None,
    video: VideoOpt = False,
    video_length: VideoLengthOpt = 200,
    video_interval: Annotated[int, typer.Option(
        help="Env steps from one video's start to the next.")] = 2000,
    logs_dir: LogsDir = None,
) -> None:
    """Train a policy; the run goes to logs/<framework>/<task>/<time>/.

    Example: lab train --task cartpole --framework sb3 --set agent.learning_rate=1e-3 --video
    """
    settings = VideoSettings(video_length, video_interval) if video else None
    outcome = training.train(
        task, framework, num_envs=num_envs, seed=seed, max_iterations=max_iterations,
        device=device, backend=backend, run_name=run_name, overrides=set_ or [],
        config_file=config_file, checkpoint=checkpoint, logs_dir=logs_dir, console=err,
        video=settings)
    s = outcome.summary
    figures = [f"{s['state']}", f"{s['iterations']} iterations", f"{s['steps']:,} steps",
               f"{s['wall_time_s']:.1f} s"]
    if s["mean_return"] is not None:
        figures.append(f"mean return {s['mean_return']:.1f}")
    if s["success_rate"] is not None:
        figures.append(f"success {s['success_rate']:.0%}")
    out.print(f"{outcome.run.dir}: " + ", ".join(figures), highlight=False, soft_wrap=True)
    if settings is not None:
        folder = videos.folder(outcome.run.dir, videos.TRAIN)
        out.print(f"videos: {folder}", highlight=False, soft_wrap=True)
    if s["state"] == "interrupted":
        raise typer.Exit(128 + int(s.get("signal", signal.SIGINT)))


@command("play")
def play_command(
    last: Annotated[bool, typer.Option("--last", help="Newest run (the default).")] = True,
    run: RunOpt = None,
    checkpoint: Annotated[Path | None, typer.Option(help="A checkpoint file.")] = None,
    task: TaskOpt = None,
    framework: FrameworkOpt = None,
    agent: Annotated[play.Agent | None, typer.Option(
        help="Play a task (--task) with zero or random actions and no checkpoint, to check it "
             "before training.")] = None,
    num_envs: Annotated[int | None, typer.Option(help="Parallel envs [episodes, max 256].")] = None,
    episodes: Annotated[int, typer.Option(help="Episodes to roll out.")] = 10,
    seed: Annotated[int, typer.Option(help="Seed of the evaluation episodes.")] = 0,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", help="With --agent: override an env setting, env.KEY=VALUE.")] = None,
    video: Annotated[bool, typer.Option(
        "--video", help="Record env 0 as mp4 into <run>/videos/play/.")] = False,
    video_length: VideoLengthOpt = 200,
    viewer: Annotated[bool, typer.Option(
        "--viewer", help="Show env 0 in MuJoCo's viewer (needs a display).")] = False,
    logs_dir: LogsDir = None,
) -> None:
    """Roll out a trained policy deterministically; print episode returns and success rate.

    Example: lab play --last --framework sb3 --episodes 100 --video
    Example: lab play --agent random --task cartpole
    """
    show = play.Show(VideoSettings(video_length, None) if video else None, viewer)
    if agent is not None:
        if task is None or run or checkpoint or framework:
            raise LabError(f"--agent {agent.value} plays a task with no checkpoint",
                           "pass --task T, and no --run, --checkpoint or --framework")
        spec, eps = play.sanity(task, agent, episodes=episodes, seed=seed, num_envs=num_envs,
                                overrides=set_ or [], show=show, logs_dir=logs_dir)
        _print_episodes(eps, f"{agent.value} agent · {task}", bool(spec.success))
        return
    if set_:
        raise LabError("--set applies to --agent only", "a run plays with its own params")
    loaded, eps = play.play(episodes=episodes, seed=seed, run_dir=run, checkpoint=checkpoint,
                            task=task, framework=framework, num_envs=num_envs, logs_dir=logs_dir,
                            show=show)
    _print_episodes(eps, f"{loaded.run.dir} · {loaded.checkpoint.path.name}",
                    bool(loaded.spec.success))


def _print_episodes(eps: play.Episodes, title: str, has_success: bool) -> None:
    table = _table("episode", "return", "length", "ended by", "success", title=title)
    for i, (r, n, cause, ok) in enumerate(zip(eps.returns, eps.lengths, eps.causes,
                                              eps.successes, strict=True)):
        table.add_row(str(i), f"{r:.1f}", str(n), cause,
                      ("yes" if ok else "no") if has_success else "-")
    out.print(table)
    causes = Counter(eps.causes)
    ended = ", ".join(f"{cause} {count}" for cause, count in causes.most_common())
    success = f"success rate {eps.success_rate:.0%}" if has_success else "no success criterion"
    out.print(f"{len(eps.returns)} episodes: mean return {eps.mean_return:.1f}, {success}; "
              f"ended by {ended}", highlight=False, soft_wrap=True)
    for path in eps.videos:
        out.print(f"video: {path}", highlight=False, soft_wrap=True)


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
    device: Annotated[str | None, typer.Option(
        help="Torch device of the env [cuda with the warp backend, else cpu].")] = None,
    framework: Annotated[str | None, typer.Option(
        "--framework", "-f", help="Also time a short training run with this framework.")] = None,
    seconds: Annotated[float, typer.Option(help="Seconds per measurement.")] = 3.0,
    threads: Annotated[int | None, typer.Option(
        help="cpu backend: threads that step the physics [the cores this process may use].")
    ] = None,
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
                       seconds=seconds, threads=threads)
    if as_json:
        out.print_json(json.dumps([row.as_dict() for row in rows]))
        return
    columns = ["task", "backend", "threads", "envs", "env-steps/s"]
    if framework:
        columns += ["framework", "training steps/s"]
    table = _table(*columns, title="lab bench")
    for row in rows:
        cells = [row.task, row.backend, str(row.threads or "-"), str(row.num_envs),
                 f"{row.env_steps_per_s:,.0f}"]
        if framework:
            cells += [row.framework, f"{row.train_steps_per_s:,.0f}"]
        table.add_row(*cells)
    out.print(table)


@command("runs")
def runs_command(
    task: TaskOpt = None,
    framework: FrameworkOpt = None,
    state: Annotated[str | None, typer.Option(
        help="Filter by state: finished, interrupted, failed or running.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    logs_dir: LogsDir = None,
) -> None:
    """List runs, newest first: task, framework, start, steps, wall time, final mean return,
    success rate and state ("failed": it stopped on an error or died without a summary).

    Example: lab runs --task cartpole --state finished
    """
    logs_dir = logs_dir or runs.default_logs_dir()
    rows = runs.table(logs_dir, task, framework, state)
    if as_json:
        out.print_json(json.dumps([row.as_dict() for row in rows]))
        return
    table = _table(Column("started", no_wrap=True), "task", "framework", "name", "steps",
                   "wall time", "return", "success", Column("state", no_wrap=True),
                   title=f"{len(rows)} runs in {logs_dir}")
    for row in rows:
        table.add_row(
            row.started.replace("T", " ")[:16], row.task, row.framework, runs.run_name(row.dir),
            _figure(row.steps, "{:,}"), _figure(row.wall_time_s, "{:.1f} s"),
            _figure(row.mean_return, "{:.1f}"), _figure(row.success_rate, "{:.0%}"), row.state)
    out.print(table)


def _figure(value: float | None, fmt: str) -> str:
    return "-" if value is None else fmt.format(value)


@command("plot")
def plot_command(
    run_dirs: Annotated[list[Path] | None, typer.Argument(
        help="Run directories [the newest run, or --last N]", show_default=False)] = None,
    metric: Annotated[str, typer.Option(help="TensorBoard tag to plot.")] = plots.DEFAULT_METRIC,
    output: Annotated[Path, typer.Option("--output", "-o", help="PNG file to write.")] =
        plots.DEFAULT_OUTPUT,
    last: Annotated[int, typer.Option(help="Without RUN: the N newest runs.")] = 1,
    task: TaskOpt = None,
    framework: FrameworkOpt = None,
    logs_dir: LogsDir = None,
) -> None:
    """Draw learning curves (a metric against env steps) of one or more runs into a PNG.

    Example: lab plot --task cartpole --last 3 -o cartpole.png
    """
    selected = plots.select(run_dirs or [], logs_dir=logs_dir, last=last, task=task,
                            framework=framework)
    result = plots.plot(selected, metric, output)
    for run in result.skipped:
        err.print(f"note: {run.dir} has no '{metric}' yet; left out", highlight=False)
    out.print(f"wrote {result.path}: {metric} of {len(result.plotted)} run(s)", highlight=False,
              soft_wrap=True)


@command("show", group=config_app)
def config_show(
    task: Annotated[str, typer.Option("--task", "-t", help="Task, see `lab list`.",
                                      autocompletion=complete_task)],
    framework: Annotated[str, typer.Option("--framework", "-f", help="Learning library.",
                                           autocompletion=complete_framework)],
    set_: SetOpt = None,
    config_file: ConfigOpt = None,
) -> None:
    """Print the fully resolved env and agent config as YAML, fit for `lab train --config`.

    Example: lab config show --task cartpole --framework sb3 --set agent.n_epochs=10 > my.yaml
    """
    env_cfg, agent_cfg = training.resolve_configs(
        plugins.get_task(task), plugins.get_framework(framework), config_file=config_file,
        overrides=set_ or [])
    out.print(config.dump(env_cfg, agent_cfg), end="", highlight=False, soft_wrap=True)


@command("info")
def info_command() -> None:
    """Print versions of lab, MuJoCo, torch and the frameworks, the GL backend, and whether
    rendering, CUDA and MuJoCo Warp work here.

    Example: lab info
    """
    table = _table("", "", title=f"lab {__version__}")
    for name, value in info.collect().items():
        table.add_row(name, value)
    out.print(table)


def main() -> None:
    app()
