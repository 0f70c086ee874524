"""`lab train` as a library call: plan, say what is about to happen, then run the session.
SIGINT/SIGTERM from the first line on stop it cleanly: before the run dir exists, with nothing
written (Interrupted); after, with a checkpoint and state 'interrupted'."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console

from labcli.envs.cores import cores
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.runs import interrupt, rundir
from labcli.runs.plan import plan
from labcli.runs.ranks import from_environment
from labcli.runs.video import VideoSettings

if TYPE_CHECKING:
    from labcli.runs.context import IterationHook
    from labcli.runs.launcher import Launch
    from labcli.runs.session import TrainOutcome


def train(task: str, framework: str, *, num_envs: int | None = None, seed: int | None = None,
          max_iterations: int | None = None, device: str | None = None,
          backend: str | None = None, run_name: str | None = None,
          overrides: Sequence[str] = (), config_file: Path | None = None,
          checkpoint: str | None = None, logs_dir: Path | None = None,
          console: Console | None = None, command: Sequence[str] | None = None,
          video: VideoSettings | None = None,
          on_iteration: IterationHook | None = None,
          logger: str = "tensorboard") -> TrainOutcome:
    """Train `task` with `framework`; everything is validated before anything is written. With
    `video`, env 0 is recorded into <run dir>/videos/train/. `on_iteration(iteration, steps,
    figures)` is told every iteration's logged figures; returning True stops the run as Ctrl-C
    would (checkpointed, state 'interrupted'). `logger`: "wandb" logs to Weights & Biases too
    (`labcli.runs.loggers`)."""
    console = console or Console(stderr=True)
    ranks = from_environment()  # one of several, when torchrun started this process
    if not ranks.writer:
        console = Console(quiet=True)  # rank 0 says it all
    # A signal lab's console script recorded while this command started counts as the first.
    with interrupt.deferred(interrupt.StopRequest(interrupt.startup.signum)) as stop:
        the_plan = plan(task, framework, num_envs=num_envs, seed=seed,
                        max_iterations=max_iterations, device=device, backend=backend,
                        run_name=run_name, overrides=overrides, config_file=config_file,
                        checkpoint=checkpoint, logs_dir=logs_dir, video=video,
                        ranks=ranks.world_size, logger=logger)
        for failure in registry.loaded().failures:  # what they provide is missing: say so
            console.print(f"warning: plugin '{failure.plugin}' ({failure.provider}) failed to "
                          f"load: {failure.error}", highlight=False, soft_wrap=True)
        console.print(the_plan.describe(), highlight=False, soft_wrap=True)
        for warning in the_plan.warnings:
            console.print(f"warning: {warning}", highlight=False, markup=False, soft_wrap=True)
        # torch, MuJoCo and the framework's library: seconds, after the line above.
        from labcli.runs import session

        return session.run(the_plan, stop, console,
                           list(command) if command is not None else None, on_iteration,
                           ranks)


def launch(launch: Launch, argv: Sequence[str], task: str, framework: str, *,
           console: Console | None = None, **options: Any) -> int:
    """`lab train <argv>` on data-parallel ranks started here (`lab train --nproc`): the
    options are checked as a rank will check them, before any rank starts; returns the exit
    code."""
    console = console or Console(stderr=True)
    if from_environment().active:
        raise LabError("--nproc inside a rank that torchrun started",
                       "leave out --nproc under torchrun, or run lab train --nproc alone")
    the_plan = plan(task, framework, ranks=launch.check(), **options)
    rundir.check_writable(the_plan.write_dir)
    import torch

    from labcli.runs.launcher import launch as run_ranks
    from labcli.runs.session import check_device

    device = check_device(options.get("device"), options.get("backend"))
    gpus = torch.cuda.device_count()
    if device.startswith("cuda") and launch.nproc > gpus:
        raise LabError(f"--nproc {launch.nproc} on a host with {gpus} GPU(s): each rank takes "
                       "one", f"pass --nproc {gpus}, or --backend cpu for ranks on the CPU")
    if not device.startswith("cuda") and launch.nproc > cores():
        raise LabError(f"--nproc {launch.nproc} on a host with {cores()} core(s) for lab: each "
                       "rank steps its envs on at least one", f"pass at most --nproc {cores()}")

    return run_ranks(launch, argv, console)
