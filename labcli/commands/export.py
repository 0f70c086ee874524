"""`lab export`."""

from __future__ import annotations

from typing import Annotated, Literal

import typer

from labcli.commands.common import (
    CheckpointOpt,
    FrameworkOpt,
    LastOpt,
    LogsDir,
    RunOpt,
    RunSetOpt,
    TaskOpt,
    err,
    say,
)


def export(
    fmt: Annotated[Literal["onnx", "jit"], typer.Argument(help="onnx or jit (TorchScript).")],
    last: LastOpt = True,
    run: RunOpt = None,
    checkpoint: CheckpointOpt = None,
    task: TaskOpt = None,
    framework: FrameworkOpt = None,
    logs_dir: LogsDir = None,
    set_: RunSetOpt = None,
) -> None:
    """Export a policy (normalizer folded in) to <run>/exported/ and check it against torch.

    Example: lab export onnx --last
    """
    from labcli.runs import export as exports

    result = exports.export(fmt, run_dir=run, checkpoint=checkpoint, task=task,
                            framework=framework, logs_dir=logs_dir, overrides=set_ or [])
    say(f"wrote {result.path} and {result.metadata.name}; max abs difference from torch "
        f"{result.max_abs_diff:.2e} over {result.checked} observations")
    if result.note is not None:
        err().print(result.note, highlight=False, soft_wrap=True)
