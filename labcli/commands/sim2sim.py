"""`lab sim2sim`."""

from __future__ import annotations

from typing import Annotated

import typer

from labcli.commands.common import FrameworkOpt, LastOpt, LogsDir, RunOpt, TaskOpt, say


def sim2sim(
    last: LastOpt = True,
    run: RunOpt = None,
    task: TaskOpt = None,
    framework: FrameworkOpt = None,
    logs_dir: LogsDir = None,
    episodes: Annotated[int, typer.Option(help="Episodes on each side, one per env.")] = 16,
    seed: Annotated[int, typer.Option(help="Seed of lab's episodes (start states and "
                                      "commands, which plain MuJoCo replays).")] = 0,
    tolerance: Annotated[float, typer.Option(help="Largest difference of the success rates "
                                             "that passes.")] = 0.1,
) -> None:
    """Run a run's ONNX export in plain MuJoCo (mj_step, NumPy, onnxruntime; observations built
    from its metadata alone) beside `lab play`, from the same start states under the same
    commands; exit 1 when their success rates differ by more than --tolerance.

    Example: lab export onnx --last && lab sim2sim --last --episodes 32
    """
    from labcli.runs import closed_loop

    result = closed_loop.check(run_dir=run, task=task, framework=framework, logs_dir=logs_dir,
                               episodes=episodes, seed=seed, tolerance=tolerance)
    for name, side in (("lab play", result.lab), ("plain MuJoCo", result.plain)):
        say(f"{name:>12}: success {side.success:.2f}, falls {side.falls}, mean tracking errors "
            f"{side.lin_vel_error:.3f} m/s (xy) and {side.yaw_rate_error:.3f} rad/s (yaw rate)")
    say(f"first observation: lab's and the metadata's differ by at most {result.obs_diff:.2f} "
        f"of the tolerance ({result.obs_worst}); joint positions after the first step by "
        f"{result.step_diff:.1e} rad ({result.step_worst})")
    verdict = "agree" if result.passed else "DISAGREE"
    say(f"{result.export}: {result.episodes} episodes each; {verdict} (observations within "
        f"{closed_loop.OBS_TOLERANCE:.0e}, height scans' medians within "
        f"{closed_loop.SCAN_TOLERANCE} m, "
        f"first steps within {closed_loop.STEP_TOLERANCE} rad, "
        f"success rates within {result.tolerance:.2f})")
    if not result.passed:
        raise typer.Exit(1)
