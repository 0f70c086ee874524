"""How often a task's physics runs away under violent actions, per physics setting.

  python bench/bench_stability.py --task go1-flat [--envs 1024] [--steps 1500] [--sigma 5]
      --variant "env.cone=pyramidal env.impratio=100" --variant "env.cone=pyramidal env.impratio=1"

Each variant (space-separated `--set`s over `--set`s common to all) steps the same random
actions, N(0, sigma) per joint (resets included, on the cpu backend, one process), and counts the
env steps in which a joint or the base moved faster than 30, 100 and 1,000 (rad/s or m/s), the
rewards larger than 1 in size, and the largest. go1-flat's per-step rewards stay under 1 under
such actions when its physics holds (0.85 at the most in 1.5 M env steps). lab resets an env only
past `env.unstable_velocity` (`Sim.unstable`; 1e6 unless a task sets less): a state between
those speeds is stepped, observed and rewarded, and counted here.
"""

from __future__ import annotations

import argparse
import shlex

import torch
from rich.console import Console
from rich.table import Table

from labcli.gym import make_env

SPEEDS = (30, 100, 1000)


def count(task: str, sets: list[str], envs: int, steps: int, sigma: float) -> dict:
    """The runaway counts of `steps` env steps of `envs` envs under N(0, sigma) actions."""
    # One process (threads=1: no shards), whose physics state this reads.
    env = make_env(task, envs, backend="cpu", seed=1, overrides=sets, threads=1)
    env.reset(seed=1)
    actions = torch.Generator().manual_seed(0)
    past = dict.fromkeys(SPEEDS, 0)
    large, worst = 0, 0.0
    for _ in range(steps):
        action = torch.randn(envs, env.single_action_space.shape[0], generator=actions) * sigma
        _, reward, *_ = env.step(action)
        speed = env.sim.qvel.abs().amax(dim=1)
        for limit in SPEEDS:
            past[limit] += int((speed > limit).sum())
        large += int((reward.abs() > 1).sum())
        worst = max(worst, float(reward.abs().max()))
    env.close()
    return {"past": past, "large": large, "worst": worst}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="go1-flat")
    parser.add_argument("--envs", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--sigma", type=float, default=5.0)
    parser.add_argument("--set", dest="sets", action="append", default=[])
    parser.add_argument("--variant", action="append", default=[])
    args = parser.parse_args()
    table = Table(title=f"{args.task}: {args.steps:,} steps of {args.envs:,} envs, actions "
                        f"N(0, {args.sigma})")
    for column in ("variant", *(f"steps past {s}" for s in SPEEDS), "rewards > 1", "largest"):
        table.add_column(column, justify="left" if column == "variant" else "right")
    for variant in args.variant or [""]:
        result = count(args.task, args.sets + shlex.split(variant), args.envs, args.steps,
                       args.sigma)
        table.add_row(variant or "the task's", *(f"{result['past'][s]:,}" for s in SPEEDS),
                      f"{result['large']:,}", f"{result['worst']:.3g}")
    Console().print(table)


if __name__ == "__main__":
    main()
