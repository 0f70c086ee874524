"""`lab train`."""

from __future__ import annotations

import signal
import sys
from typing import Annotated, Literal

import typer

from labcli.commands.common import (
    ConfigOpt,
    FrameworkArg,
    LogsDir,
    SetOpt,
    TaskArg,
    VideoLengthOpt,
    err,
    say,
)


def train(
    task: TaskArg,
    framework: FrameworkArg,
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
        help="Resume from a checkpoint file, a run dir, 'latest' or 'best' (the highest "
        "success, then return, of the newest run).")] = None,
    video: Annotated[bool, typer.Option("--video", help="Record env 0 as mp4.")] = False,
    video_length: VideoLengthOpt = 200,
    video_interval: Annotated[int, typer.Option(
        help="Env steps from one video's start to the next.")] = 2000,
    logs_dir: LogsDir = None,
    logger: Annotated[Literal["tensorboard", "wandb"], typer.Option(
        help="Where the figures go: TensorBoard (the run dir's event files), or Weights & "
             "Biases as well (pip install 'lab[wandb]'; WANDB_PROJECT, WANDB_MODE=offline).")
    ] = "tensorboard",
    nproc: Annotated[int | None, typer.Option(
        help="Data-parallel ranks on this host, each with --num-envs envs (rsl_rl, skrl): "
             "the batch grows with the ranks, and so does rsl_rl's KL target "
             "(agent.kl_grows_with_ranks). For one GPU's batch split over the ranks instead, "
             "give --num-envs E/N and --set agent.kl_grows_with_ranks=false. The same as "
             "torchrun --nproc-per-node N -m labcli train ... (docs/scale.md)")] = None,
    nnodes: Annotated[str | None, typer.Option(
        help="With --nproc: hosts taking part, N or MIN:MAX (run the command on each).")] = None,
    rdzv_endpoint: Annotated[str | None, typer.Option(
        help="With --nnodes: HOST:PORT where the hosts' ranks meet.")] = None,
    rdzv_id: Annotated[str | None, typer.Option(
        help="With --nnodes: the same id on every host of one run.")] = None,
) -> None:
    """Train a policy; the run goes to logs/<framework>/<task>/<time>/.

    Example: lab train --task cartpole --framework sb3 --set agent.learning_rate=1e-3 --video
    """
    from labcli.runs import training
    from labcli.runs import video as videos

    settings = videos.VideoSettings(video_length, video_interval) if video else None
    options = dict(num_envs=num_envs, seed=seed, max_iterations=max_iterations, device=device,
                   backend=backend, run_name=run_name, overrides=set_ or [],
                   config_file=config_file, checkpoint=checkpoint, logs_dir=logs_dir,
                   video=settings, logger=logger)
    if (nproc, nnodes, rdzv_endpoint, rdzv_id) != (None, None, None, None):
        from labcli.runs.launcher import Launch

        launch = Launch(1 if nproc is None else nproc, nnodes or "1", rdzv_endpoint, rdzv_id)
        raise typer.Exit(training.launch(launch, sys.argv[1:], task, framework, console=err(),
                                         **options))
    outcome = training.train(task, framework, console=err(), **options)
    if not outcome.ranks.writer:
        return  # rank 0 says how the run went
    s = outcome.summary
    figures = [f"{s['state']}", f"{s['iterations']} iterations", f"{s['steps']:,} steps",
               f"{s['wall_time_s']:.1f} s"]
    if s["mean_return"] is not None:
        figures.append(f"mean return {s['mean_return']:.1f}")
    if s["success_rate"] is not None:
        figures.append(f"success {s['success_rate']:.0%}")
    if s.get("terrain_level") is not None:
        figures.append(f"terrain level {s['terrain_level']:.1f}")
    say(f"{outcome.run.dir}: " + ", ".join(figures))
    if settings is not None:
        say(f"videos: {videos.folder(outcome.run.dir, videos.TRAIN)}")
    if s["state"] == "interrupted":
        raise typer.Exit(128 + int(s.get("signal", signal.SIGINT)))
