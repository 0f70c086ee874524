"""lab's robot tasks on the cpu backend beside their limit and beside gymnasium, in one run.

  python bench/bench_robots.py [--tasks ant,humanoid] [--envs 64,256,1024] [--seconds 3]
                               [--repeats 3] [--json FILE]

Per task and env count, env-steps/s (random actions, resets included) of
- lab: `LabVecEnv` on the cpu backend, torch tensors out (as `lab bench`);
- rollout: raw `mujoco.rollout` of the env's own model (sensors included) with the same
  decimation and threads, no task code (`labcli.runs.bench.rollout_rate`, as `lab bench`);
- gym-sync: gymnasium's `Ant-v5` / `Humanoid-v5` in a `SyncVectorEnv`, what users run today.
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

from labcli.envs.env import LabVecEnv  # noqa: E402
from labcli.plugins import registry  # noqa: E402
from labcli.runs.bench import env_rate, rate, rollout_rate  # noqa: E402

GYM_IDS = {"ant": "Ant-v5", "humanoid": "Humanoid-v5"}


def lab_and_rollout(task: str, num_envs: int, seconds: float) -> tuple[float, float, int]:
    spec = registry.get_task(task)
    env = LabVecEnv(spec, spec.config_class(num_envs=num_envs), backend="cpu")
    try:
        lab = env_rate(env, seconds)
        raw = rollout_rate(env.sim.model, num_envs, env.cfg.decimation, env.sim.nthread, seconds)
        return lab, raw, env.cfg.decimation
    finally:
        env.close()


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
                gym_rate, frame_skip = gym_sync(task, n, args.seconds)
                runs[task, "gym-sync", n].append(gym_rate)
                substeps[task, "lab"], substeps[task, "gym-sync"] = decimation, frame_skip
    median = {key: statistics.median(values) for key, values in runs.items()}
    for task in tasks:
        table = Table(title=f"{task}: env-steps/s, random actions, resets included (median of "
                            f"{args.repeats}); physics steps per env step: lab "
                            f"{substeps[task, 'lab']}, {GYM_IDS[task]} "
                            f"{substeps[task, 'gym-sync']}")
        for col in ("N", "lab", "rollout", f"{GYM_IDS[task]} sync", "lab / rollout",
                    "lab / gym (env steps)", "lab / gym (physics steps)"):
            table.add_column(col, justify="right")
        for n in counts:
            lab, raw, gym_rate = (median[task, k, n] for k in ("lab", "rollout", "gym-sync"))
            physics = (lab * substeps[task, "lab"]) / (gym_rate * substeps[task, "gym-sync"])
            table.add_row(str(n), fmt(lab), fmt(raw), fmt(gym_rate), ratio(lab, raw),
                          ratio(lab, gym_rate), f"{physics:.2f}")
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
