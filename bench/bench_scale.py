"""Data-parallel training on several GPUs against one: steps/s and time to success.

  python bench/bench_scale.py [--task go1-flat] [--frameworks rsl_rl,skrl] [--success 0.9]
                              [--json FILE] RUN [RUN ...]

Each RUN is `lab train`'s extra arguments in one string, the first a rank count: "1" is one
process on one GPU, "2" is `--nproc 2`, "2 --set agent.num_mini_batches=8" a variant. Every run
is `lab train --task TASK --framework F --backend warp` as a user runs it, in a throwaway logs
dir, one after another; warm MuJoCo Warp's kernel cache with a first run before timing. From
each run's TensorBoard events: median training steps/s (all ranks' steps, iterations after the
second), median learning phase per iteration (where the library logs it), seconds of training
and steps until the logged success rate first reached --success, and the final success rate;
each beside the first run's of the same framework (its ratio).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from labcli.envs import metrics
from labcli.runs.bench import time_to_success

LEARNING_TIME = {"rsl_rl": "Perf/learning_time"}


def scalars(run_dir: Path, tag: str) -> list[float]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(run_dir), size_guidance={"scalars": 0})
    events.Reload()
    if tag not in events.Tags()["scalars"]:
        return []
    return [s.value for s in events.Scalars(tag)]


def median_after_two(values: list[float]) -> float | None:
    return statistics.median(values[2:] or values) if values else None


def figures(run_dir: Path, success: float) -> dict:
    """What a finished (or stopped) run's summary and TensorBoard events say: its seconds and
    steps of training, final success, median steps/s, and the seconds and steps until the
    logged success rate first reached `success` (None if never)."""
    summary = json.loads((run_dir / "summary.json").read_text())
    reached = time_to_success(run_dir, success)
    return {
        "state": summary["state"], "training_s": summary["wall_time_s"],
        "steps": summary["steps"], "final_success": summary["success_rate"],
        "steps_per_s": median_after_two(scalars(run_dir, metrics.STEPS_PER_S)),
        "success_s": reached[0] if reached else None,
        "success_steps": reached[1] if reached else None,
    }


def train(task: str, framework: str, run: str, success: float) -> dict:
    nproc, *extra = shlex.split(run)
    cmd = ["lab", "train", "--task", task, "--framework", framework, "--backend", "warp",
           *(["--nproc", nproc] if int(nproc) > 1 else []), *extra]
    with tempfile.TemporaryDirectory(prefix="bench_scale_") as logs:
        start = time.perf_counter()
        done = subprocess.run(cmd, env={**os.environ, "LAB_LOGS_DIR": logs},
                              capture_output=True, text=True)
        wall = time.perf_counter() - start
        if done.returncode:
            print(f"{shlex.join(cmd)}: exit {done.returncode}\n{done.stderr[-3000:]}", flush=True)
            return {"framework": framework, "run": run, "exit": done.returncode}
        (run_dir,) = Path(logs, framework, task).iterdir()
        row = {
            "framework": framework, "run": run, "gpus": int(nproc), "wall_s": wall,
            **figures(run_dir, success),
            "learning_s": median_after_two(scalars(run_dir, LEARNING_TIME.get(framework, ""))),
        }
    print(json.dumps(row), flush=True)
    return row


def ratio(value: float | None, base: float | None) -> str:
    return f"{value / base:.2f}×" if value and base else "-"


def report(rows: list[dict], success: float) -> None:
    bases: dict[str, dict] = {}
    print(f"\n| framework | run | steps/s | vs first | learning s/it | success {success} after "
          "(s) | vs first | steps to it | final success |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for row in rows:
        if "exit" in row:
            print(f"| {row['framework']} | {row['run']} | exit {row['exit']} |  |  |  |  |  |  |")
            continue
        base = bases.setdefault(row["framework"], row)
        learning = f"{row['learning_s']:.3f}" if row["learning_s"] is not None else "-"
        seconds = f"{row['success_s']:.1f}" if row["success_s"] is not None else "never"
        steps = f"{row['success_steps']:,}" if row["success_steps"] is not None else "-"
        print(f"| {row['framework']} | `{row['run']}` | {row['steps_per_s']:,.0f} | "
              f"{ratio(row['steps_per_s'], base['steps_per_s'])} | {learning} | {seconds} | "
              f"{ratio(row['success_s'], base['success_s'])} | {steps} | "
              f"{row['final_success']:.2f} |")


def versions() -> str:
    import importlib.metadata as md

    names = ("mujoco", "mujoco-warp", "warp-lang", "rsl-rl-lib", "skrl")
    found = ", ".join(f"{n} {md.version(n)}" for n in names)
    gpus = [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())]
    return f"{len(gpus)}× {gpus[0] if gpus else 'no GPU'}; torch {torch.__version__}, {found}"


def conclude(rows: list[dict], about: dict[str, str], path: Path | None) -> None:
    """Write `rows` and what they ran on (`about`) to `path`, if given; exit 1 if a run failed."""
    if path:
        path.write_text(json.dumps({**about, "rows": rows}, indent=1))
    sys.exit(any("exit" in row for row in rows))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", metavar="RUN")
    p.add_argument("--task", default="go1-flat")
    p.add_argument("--frameworks", default="rsl_rl")
    p.add_argument("--success", type=float, default=0.9)
    p.add_argument("--json", type=Path, help="write the rows here")
    a = p.parse_args()
    about = versions()
    print(about, flush=True)
    rows = [train(a.task, framework, run, a.success)
            for framework in a.frameworks.split(",") for run in a.runs]
    report(rows, a.success)
    conclude(rows, {"versions": about}, a.json)


if __name__ == "__main__":
    main()
