"""Where a training iteration's time goes, per framework, at the task's defaults.

  python bench/bench_train.py [--task cartpole] [--frameworks sb3,rsl_rl,skrl,rl_games]
                              [--iterations 30] [--backend cpu|warp] [--num-envs N]
                              [--json FILE]

Runs `lab train` in this process (a throwaway logs dir) with timers around `LabVecEnv.step`
and lab's `TrainContext.end_iteration`, and splits each iteration, from one `end_iteration` to the
next, into:
  env step      inside `LabVecEnv.step`: actions, physics substeps, task terms, resets, stats
  rollout rest  the rest of the rollout, from its first env step to its last: the policy's
                forward pass and sampling, the adapter's conversions, the library's buffers
  update        from the rollout's last env step to `end_iteration`: returns, advantages and
                the gradient epochs (plus any per-iteration work of the library)
  lab           inside `end_iteration`: statistics, TensorBoard, the kept last good state,
                checkpoints
Medians over the iterations after the first two. On a GPU, times are host times: with the
env's step replayed as a CUDA graph, "env step" is what the host waits for the GPU.
"""

from __future__ import annotations

import argparse
import io
import json
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import torch
from rich.console import Console
from rich.table import Table

from labcli.envs.env import LabVecEnv
from labcli.runs import session, training
from labcli.runs.context import RunContext

PARTS = ("env step", "rollout rest", "update", "lab")
console = Console(width=None if sys.stdout.isatty() else 150)


class Clock:
    """Timestamps of env steps and iteration ends, turned into per-iteration parts."""

    def __init__(self, sync: Callable[[], None]):
        self.sync = sync
        self.iterations: list[dict[str, float]] = []
        self._reset(time.perf_counter())

    def _reset(self, now: float) -> None:
        self.start, self.env, self.first_step, self.last_step = now, 0.0, None, now
        self.steps = 0

    def step(self, fn: Callable, *args, **kwargs):
        self.sync()
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        self.sync()
        t1 = time.perf_counter()
        self.env += t1 - t0
        self.first_step = t0 if self.first_step is None else self.first_step
        self.last_step = t1
        self.steps += 1
        return out

    def end_iteration(self, fn: Callable, *args, **kwargs):
        self.sync()
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        t1 = time.perf_counter()
        rollout = self.last_step - (self.first_step or self.last_step)
        self.iterations.append({
            "env step": self.env, "rollout rest": rollout - self.env,
            "update": t0 - self.last_step, "lab": t1 - t0, "whole": t1 - self.start,
            "env steps": self.steps})
        self._reset(t1)
        return out


def breakdown(task: str, framework: str, iterations: int, backend: str | None,
              num_envs: int | None) -> dict:
    device = session.check_device(None, backend)
    sync = torch.cuda.synchronize if torch.device(device).type == "cuda" else (lambda: None)
    clock = Clock(sync)
    step, end_iteration = LabVecEnv.step, RunContext.end_iteration
    LabVecEnv.step = lambda self, *a, **k: clock.step(step, self, *a, **k)
    RunContext.end_iteration = lambda self, *a, **k: clock.end_iteration(
        end_iteration, self, *a, **k)
    try:
        with tempfile.TemporaryDirectory(prefix="bench_train_") as logs:
            outcome = training.train(task, framework, max_iterations=iterations,
                                     num_envs=num_envs, backend=backend, logs_dir=Path(logs),
                                     console=Console(file=io.StringIO()),
                                     command=["bench_train.py"])
    finally:
        LabVecEnv.step, RunContext.end_iteration = step, end_iteration
    kept = clock.iterations[2:] or clock.iterations
    med = {k: statistics.median(it[k] for it in kept) for k in (*PARTS, "whole", "env steps")}
    steps = outcome.summary["steps"]
    return {"framework": framework, "num_envs": num_envs or "default",
            "iterations": len(clock.iterations), "steps": steps,
            "steps_per_s": steps / outcome.summary["wall_time_s"], "median_s": med}


def table(rows: list[dict], task: str) -> None:
    out = Table(title=f"lab train --task {task}: one iteration, median seconds (share)")
    for col in ("framework", "env steps / it.", *PARTS, "whole iteration", "steps/s (run)"):
        out.add_column(col, justify="right")
    for r in rows:
        m = r["median_s"]
        whole = m["whole"]
        out.add_row(r["framework"], f"{m['env steps']:.0f}",
                    *(f"{m[p]:.3f} ({m[p] / whole:.0%})" for p in PARTS), f"{whole:.3f}",
                    f"{r['steps_per_s']:,.0f}")
    console.print(out)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="cartpole")
    p.add_argument("--frameworks", default="sb3,rsl_rl,skrl,rl_games")
    p.add_argument("--iterations", type=int, default=30)
    p.add_argument("--backend", choices=("cpu", "warp"))
    p.add_argument("--num-envs", type=int, help="the framework's default for the task if unset")
    p.add_argument("--json", type=Path)
    a = p.parse_args()
    rows = [breakdown(a.task, fw, a.iterations, a.backend, a.num_envs)
            for fw in a.frameworks.split(",") if fw]
    table(rows, a.task)
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
