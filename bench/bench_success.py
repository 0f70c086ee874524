"""Robot tasks trained with default flags: seconds to success, seed by seed, beside the time
each task should take: on a 2-core laptop (`--backend cpu`) or on one GPU (`--backend warp`).

  python bench/bench_success.py [--tasks ant,humanoid] [--framework rsl_rl]
                                [--backend cpu|warp] [--seeds 0,1,2] [--success 0.9]
                                [--played] [--stop SECONDS] [--set KEY=VALUE ...]
                                [--json FILE] [--keep DIR]

Each run is `lab train --task T --framework F --seed S --backend B` as a user runs it (by
this Python's `-m labcli`), in a throwaway logs dir, one after another; it is stopped (Ctrl-C,
a checkpoint) once its training has lasted twice the task's goal (or `--stop` seconds, counted
from its TensorBoard file's appearance, after start-up), else it ends by itself.
`--keep DIR` keeps each run, under DIR/TASK-sSEED, to be played or exported afterwards.
`--set` passes a setting on to every run (a variant of the defaults held to the same goals,
e.g. `--set agent.symmetry_augmentation=true`).
From its TensorBoard events: the seconds of training (from the run's first event, after
start-up) and steps until the logged success rate first reached --success, the median
steps/s, and the final success rate; then, per task, the median over the seeds and how many
seeds got there within the goal (a run that never got there counts as never, and a median of
nevers is never). `--played` judges each run by its checkpoints instead, as `lab play` plays
them (64 episodes without the exploration noise, on the CPU): the seconds and steps of
training at which the first one that reached --success was saved (for a run that never got
there, its best checkpoint's rate). With `--backend warp` a
run's checkpoints are played while the next run trains. Training's own success
counts episodes played under the noise, which can hide a policy that has learnt.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import importlib.metadata
import json
import os
import platform
import shlex
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_scale import conclude, figures  # noqa: E402

from labcli.runs.bench import cpu_name, played_to_success  # noqa: E402

# Seconds of training to success on a 2-core machine that a robot task should take at its
# defaults: ant and humanoid as Isaac Lab's classic tasks, the robots as a laptop allows.
GOALS_S = {
    "cpu": {"ant": 180, "humanoid": 900, "go1-flat": 1200, "go2-flat": 1200, "g1-flat": 2700,
            "panda-reach": 600},
    # One GPU: the G1 walking, the Panda reaching and lifting (on three seeds of three).
    "warp": {"g1-flat": 600, "panda-reach": 60, "panda-lift": 180},
}
# Start-up (imports, the model, compiling MuJoCo Warp's kernels on a fresh machine: ~150 s for
# panda-lift) is not training: a run's time counts from when its TensorBoard file appears, and
# a run with none after this long is stopped.
START_LIMIT_S = 900
POLL_S = 2.0
# Checkpoints played at once, each in its own process on one core: on the CPU after a run, on
# all cores; on a GPU while the next run trains, on half the host's cores (the GPU would idle
# through the plays otherwise: about a minute a panda-lift run on 16 cores).
CORES = os.cpu_count() or 1
PLAY_WORKERS = {"cpu": min(8, CORES), "warp": max(1, min(8, CORES // 2))}


def stop_after(proc: subprocess.Popen, runs: Path, seconds: float) -> str:
    """Wait for `proc`; once a run under `runs` has begun its TensorBoard file, give it `seconds`
    more, then stop it as Ctrl-C does (the run checkpoints and stops). Its stderr."""
    begun = time.time()
    started = None
    while True:
        try:
            return proc.communicate(timeout=POLL_S)[1]
        except subprocess.TimeoutExpired:
            now = time.time()
            if started is None and any(f.stat().st_mtime >= begun
                                       for f in runs.glob("*/events.out.tfevents.*")):
                started = now
            if now - (started or begun) >= (START_LIMIT_S if started is None else seconds):
                proc.send_signal(signal.SIGINT)
                return proc.communicate()[1]


def train(task: str, framework: str, backend: str, seed: int, success: float,
          overrides: list[str], logs: Path, stop_s: float | None = None
          ) -> tuple[dict, Path | None]:
    """One run under logs/TASK-sSEED: its row of figures, and its folder (None if it failed)."""
    cmd = [sys.executable, "-m", "labcli", "train", "--task", task, "--framework", framework,
           "--seed", str(seed), "--backend", backend,
           *(arg for item in overrides for arg in ("--set", item))]
    limit = stop_s or 2 * GOALS_S[backend].get(task, 600)
    logs = logs / f"{task}-s{seed}"
    proc = subprocess.Popen(cmd, env={**os.environ, "LAB_LOGS_DIR": str(logs)},
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    err = stop_after(proc, Path(logs, framework, task), limit)
    if proc.returncode not in (0, 130):
        print(f"{shlex.join(cmd)}: exit {proc.returncode}\n{err[-3000:]}", flush=True)
        return {"task": task, "seed": seed, "exit": proc.returncode}, None
    # The newest: a kept folder may hold an earlier run of the same seed.
    run_dir = max(Path(logs, framework, task).iterdir(), key=lambda d: d.stat().st_mtime)
    return {"task": task, "framework": framework, "seed": seed, "set": overrides,
            **figures(run_dir, success)}, run_dir


def judge_played(row: dict, run_dir: Path, success: float, workers: int) -> None:
    """Add to `row` its run's checkpoints played up to the first that plays to `success`, and
    print it."""
    row["played"] = played_to_success(run_dir, success, workers=workers)
    print(json.dumps(row), flush=True)


def reached(row: dict) -> tuple[float | None, int | None]:
    """The seconds and steps of training to success: played checkpoints' where the row has
    them (`--played`), else the logged success rate's."""
    if "played" in row:
        first = row["played"]["reached"] or {}
        return first.get("seconds"), first.get("steps")
    return row.get("success_s"), row.get("success_steps")


def never(row: dict) -> str:
    """The cell of a run that never got there; one judged by its played checkpoints names
    the best of them."""
    rates = row.get("played", {}).get("rates")
    if not rates:
        return "never"
    iteration, rate = max(rates, key=lambda item: item[1])
    if rate == 0:
        return f"never (0 at each of {len(rates)} checkpoints)"
    return f"never (best {rate:.2f}, iteration {iteration:,})"


def median_seconds(rows: list[dict]) -> float | None:
    """The median of the seeds' seconds to success, a run that never got there as infinite."""
    times = [reached(row)[0] or float("inf") for row in rows]
    median = statistics.median(times)
    return None if median == float("inf") else median


def report(rows: list[dict], success: float, goals: dict[str, float]) -> None:
    judged = "played" if any("played" in row for row in rows) else "success"
    print(f"\n| task | seed | steps/s | {judged} {success} after | steps to it | training s | "
          "final success |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for row in rows:
        if "exit" in row:
            print(f"| {row['task']} | {row['seed']} | exit {row['exit']} |  |  |  |  |")
            continue
        reached_s, reached_steps = reached(row)
        seconds = f"{reached_s:.0f} s" if reached_s is not None else never(row)
        steps = f"{reached_steps:,}" if reached_steps is not None else "-"
        print(f"| {row['task']} | {row['seed']} | {row['steps_per_s']:,.0f} | {seconds} | "
              f"{steps} | {row['training_s']:.0f} ({row['state']}) | "
              f"{row['final_success']:.2f} |")
    print("\n| task | median over seeds | goal | seeds within it | median met |")
    print("| --- | ---: | ---: | ---: | :-: |")
    for task in dict.fromkeys(row["task"] for row in rows):
        ran = [r for r in rows if r["task"] == task]
        goal = goals.get(task)
        finished = [r for r in ran if "exit" not in r]
        median = median_seconds(finished) if finished else None
        shown = ("no run finished" if not finished
                 else f"{median:.0f} s" if median is not None else "never")
        if goal is None:  # a task without a goal on this backend: its figures alone
            print(f"| {task} | {shown} | - | - | - |")
            continue
        within = sum(1 for r in ran if (reached(r)[0] or float("inf")) <= goal)
        met = "yes" if median is not None and median <= goal else "no"
        print(f"| {task} | {shown} | {goal} s | {within} of {len(ran)} | {met} |")


def machine() -> str:
    import torch

    names = ("mujoco", "mujoco-warp", "warp-lang", "rsl-rl-lib", "skrl", "stable-baselines3",
             "rl-games")
    found = ", ".join(f"{n} {_version(n)}" for n in names)
    gpus = ", ".join(torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count()))
    return (f"{os.cpu_count()} cores ({cpu_name()})"
            f"{'; ' + gpus if gpus else ''}; Python {platform.python_version()}, torch "
            f"{torch.__version__}, {found}")


def _version(name: str) -> str:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default="ant,humanoid")
    p.add_argument("--framework", default="rsl_rl")
    p.add_argument("--backend", choices=sorted(GOALS_S), default="cpu")
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--success", type=float, default=0.9)
    p.add_argument("--played", action="store_true",
                   help="judge each run by its checkpoints played without exploration noise")
    p.add_argument("--stop", type=float, metavar="SECONDS",
                   help="stop each run after this many seconds of training (default: twice "
                        "the task's goal)")
    p.add_argument("--set", action="append", default=[], dest="overrides", metavar="KEY=VALUE",
                   help="a setting for every run, as lab train's --set (repeatable)")
    p.add_argument("--json", type=Path, help="write the rows here")
    p.add_argument("--keep", type=Path, metavar="DIR", help="keep the runs under this folder")
    a = p.parse_args()
    if a.stop is not None and a.stop <= 0:
        p.error(f"--stop must be more than 0 seconds, got {a.stop:g}")
    about = machine()
    print(about, flush=True)
    with (tempfile.TemporaryDirectory(prefix="bench_success_") as scratch,
          concurrent.futures.ThreadPoolExecutor(1) as judge):
        rows, pending = [], []
        for task in a.tasks.split(","):
            for seed in a.seeds.split(","):
                row, run_dir = train(task, a.framework, a.backend, int(seed), a.success,
                                     a.overrides, a.keep or Path(scratch), a.stop)
                rows.append(row)
                if not (a.played and run_dir):
                    print(json.dumps(row), flush=True)
                    continue
                pending.append(judge.submit(judge_played, row, run_dir, a.success,
                                            PLAY_WORKERS[a.backend]))
                if a.backend == "cpu":  # its plays would take the next run's cores
                    pending[-1].result()
        for played in pending:
            played.result()  # a play's error, raised here
    report(rows, a.success, GOALS_S[a.backend])
    conclude(rows, {"machine": about}, a.json)


if __name__ == "__main__":
    main()
