"""`lab play`."""

from __future__ import annotations

from collections import Counter
from typing import TYPE_CHECKING, Annotated, Literal

import typer

from labcli.commands.common import (
    CheckpointOpt,
    FrameworkOpt,
    LastOpt,
    LogsDir,
    RunOpt,
    TaskOpt,
    VideoLengthOpt,
    out,
    say,
    table,
)
from labcli.errors import LabError

if TYPE_CHECKING:
    from labcli.runs.play import Episodes


def play(
    last: LastOpt = True,
    run: RunOpt = None,
    checkpoint: CheckpointOpt = None,
    task: TaskOpt = None,
    framework: FrameworkOpt = None,
    agent: Annotated[Literal["zero", "random"] | None, typer.Option(
        help="Play a task (--task) with zero or random actions and no checkpoint, to check it "
             "before training.")] = None,
    num_envs: Annotated[int | None, typer.Option(help="Parallel envs [episodes, max 256].")] = None,
    episodes: Annotated[int, typer.Option(help="Episodes to roll out.")] = 10,
    seed: Annotated[int, typer.Option(help="Seed of the evaluation episodes.")] = 0,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", metavar="env.KEY=VALUE",
        help="Override an env setting (repeatable): with --agent any; for a trained run "
             "what its task lets play change, and a file its params name.")] = None,
    video: Annotated[bool, typer.Option(
        "--video", help="Record env 0 as mp4 into <run>/videos/play/<time>/.")] = False,
    video_length: VideoLengthOpt = 200,
    viewer: Annotated[bool, typer.Option(
        "--viewer", help="Show env 0 in MuJoCo's viewer (needs a display).")] = False,
    logs_dir: LogsDir = None,
) -> None:
    """Roll out a trained policy deterministically; print episode returns and success rate.

    Example: lab play --last --framework sb3 --episodes 100 --video
    Example: lab play --agent random --task cartpole
    """
    if agent is not None and (task is None or run or checkpoint or framework):
        raise LabError(f"--agent {agent} plays a task with no checkpoint",
                       "pass --task T, and no --run, --checkpoint or --framework")
    from labcli.runs import play as plays
    from labcli.runs.video import VideoSettings

    show = plays.Show(VideoSettings(video_length, None) if video else None, viewer)
    if agent is not None:
        spec, eps = plays.sanity(task, agent, episodes=episodes, seed=seed, num_envs=num_envs,
                                 overrides=set_ or [], show=show, logs_dir=logs_dir)
        _print_episodes(eps, f"{agent} agent · {task}", bool(spec.success))
        return
    loaded, eps = plays.play(episodes=episodes, seed=seed, run_dir=run, checkpoint=checkpoint,
                             task=task, framework=framework, num_envs=num_envs,
                             logs_dir=logs_dir, show=show, overrides=set_ or [])
    _print_episodes(eps, f"{loaded.run.dir} · {loaded.checkpoint.path.name}",
                    bool(loaded.spec.success))


def _print_episodes(eps: Episodes, title: str, has_success: bool) -> None:
    rows = table("episode", "return", "length", "ended by", "success", title=title)
    for i, (r, n, cause, ok) in enumerate(zip(eps.returns, eps.lengths, eps.causes,
                                              eps.successes, strict=True)):
        rows.add_row(str(i), f"{r:.1f}", str(n), cause,
                     ("yes" if ok else "no") if has_success else "-")
    out().print(rows)
    causes = Counter(eps.causes)
    ended = ", ".join(f"{cause} {count}" for cause, count in causes.most_common())
    success = f"success rate {eps.success_rate:.0%}" if has_success else "no success criterion"
    say(f"{len(eps.returns)} episodes: mean return {eps.mean_return:.1f}, {success}; "
        f"ended by {ended}")
    if eps.task_metrics:
        figures = ", ".join(f"{name} {value:.3g}" for name, value in eps.task_metrics.items())
        say(f"the task's metrics, means over the {eps.ended} episodes that ended: {figures}")
    for path in eps.videos:
        say(f"video: {path}")
