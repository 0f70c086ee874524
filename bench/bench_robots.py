"""lab's robot tasks on the cpu backend beside their limit and beside gymnasium, in one run.

  python bench/bench_robots.py [--tasks ant,humanoid] [--envs 64,256,1024] [--seconds 3]
                               [--repeats 3] [--json FILE]

Per task and env count, env-steps/s (random actions, resets included) of
- lab: the env `lab train` steps on the cpu backend (in shards on two threads or more), torch
  tensors out (`lab bench`'s rows);
- rollout: raw `mujoco.rollout` of what the env steps (its models, states and the controls its
  actuation makes of random actions) with the same decimation and threads, no task code
  (`labcli.runs.bench.rollout_steppers`, timed in turns with lab, as `lab bench`);
- gym-sync: gymnasium's `Ant-v5` / `Humanoid-v5` in a `SyncVectorEnv`, what users run today
  (tasks gymnasium has no counterpart of, as go1-flat, go without).
  Its env step is 5 physics steps of 0.01 s (Ant) or 0.003 s (Humanoid, RK4 on both) against
  lab's 2 of 1/120 s (implicitfast): the table also gives physics steps/s.
The median of --repeats interleaved runs; the load average is printed before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from collections import defaultdict
from pathlib import Path

import gymnasium as gym
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_cpu import console, fmt, fmt_load, header, ratio  # noqa: E402

from labcli.plugins import registry  # noqa: E402
from labcli.runs.bench import bench, rate  # noqa: E402

GYM_IDS = {"ant": "Ant-v5", "humanoid": "Humanoid-v5"}


def lab_and_rollout(task: str, num_envs: int, seconds: float) -> tuple[float, float, int]:
    """`lab bench`'s row: the env as `lab train` steps it (in shards on two threads or more)
    and the rollout of the states it reached."""
    (row,) = bench(task, [num_envs], backend="cpu", seconds=seconds)
    return (row.env_steps_per_s, row.rollout_steps_per_s,
            registry.get_task(task).config_class().decimation)


def gym_sync(task: str, num_envs: int, seconds: float) -> tuple[float, int]:
    one = gym.make(GYM_IDS[task])
    frame_skip = one.unwrapped.frame_skip
    one.close()
    envs = gym.make_vec(GYM_IDS[task], num_envs=num_envs, vectorization_mode="sync")
    envs.reset(seed=0)
    envs.action_space.seed(0)

    def step() -> int:
        envs.step(envs.action_space.sample())
        return num_envs

    try:
        return rate(step, seconds), frame_skip
    finally:
        envs.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default="ant,humanoid")
    parser.add_argument("--envs", default="64,256,1024")
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    tasks, counts = args.tasks.split(","), [int(n) for n in args.envs.split(",")]
    info = header()
    runs: dict[tuple[str, str, int], list[float]] = defaultdict(list)
    substeps: dict[tuple[str, str], int] = {}
    for _ in range(args.repeats):  # interleaved: a slow spell of the machine hits every kind
        for task in tasks:
            for n in counts:
                lab, raw, decimation = lab_and_rollout(task, n, args.seconds)
                runs[task, "lab", n].append(lab)
                runs[task, "rollout", n].append(raw)
                substeps[task, "lab"] = decimation
                if task in GYM_IDS:
                    gym_rate, substeps[task, "gym-sync"] = gym_sync(task, n, args.seconds)
                    runs[task, "gym-sync", n].append(gym_rate)
    median = {key: statistics.median(values) for key, values in runs.items()}
    for task in tasks:
        gym_id = GYM_IDS.get(task, "gymnasium")
        table = Table(title=f"{task}: env-steps/s, random actions, resets included (median of "
                            f"{args.repeats}); physics steps per env step: lab "
                            f"{substeps[task, 'lab']}, {gym_id} "
                            f"{substeps.get((task, 'gym-sync'), '-')}")
        for col in ("N", "lab", "rollout", f"{gym_id} sync", "lab / rollout",
                    "lab / gym (env steps)", "lab / gym (physics steps)"):
            table.add_column(col, justify="right")
        for n in counts:
            lab, raw = median[task, "lab", n], median[task, "rollout", n]
            gym_rate = median.get((task, "gym-sync", n))
            gym_cells = ["-", "-", "-"] if gym_rate is None else [
                fmt(gym_rate), ratio(lab, gym_rate),
                f"{lab * substeps[task, 'lab'] / (gym_rate * substeps[task, 'gym-sync']):.2f}"]
            table.add_row(str(n), fmt(lab), fmt(raw), gym_cells[0], ratio(lab, raw),
                          *gym_cells[1:])
        console.print(table)
    load_after = os.getloadavg()
    console.print(f"load average after: {fmt_load(load_after)}", highlight=False)
    if args.json:
        args.json.write_text(json.dumps({
            **info, "load_after": load_after, "substeps": {f"{t}/{k}": v for (t, k), v in
                                                           substeps.items()},
            "median": {f"{t}/{k}/{n}": v for (t, k, n), v in median.items()},
            "runs": {f"{t}/{k}/{n}": v for (t, k, n), v in runs.items()}}, indent=1))


if __name__ == "__main__":
    main()
