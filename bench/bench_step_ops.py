"""The torch ops of a task's env step as a GPU runs it, counted on any machine.

  python bench/bench_step_ops.py [--tasks g1-flat,yam-lift] [--num-envs 32] [--steps 10]
                                 [--blocks 1] [--top 8]

On a GPU each op of the task's code (not the physics, which is MuJoCo Warp's) is a kernel of
the env step's CUDA graph, and the GPU spends microseconds starting each: at a few thousand
envs their number, more than their size, sets the task's share of the step. Here the step runs
as on a GPU (no host reads: every reset, resample and draw runs for all envs, masked) on the
cpu backend, and torch's dispatcher counts the ops that make a kernel (views and allocations
do not), per env step: in all, the random draws among them, and the most frequent.
`--blocks 16` draws as the CPU does, a generator per block of envs (a GPU env has one).
"""

from __future__ import annotations

import argparse
import collections
from unittest import mock

import torch
from rich.console import Console
from rich.table import Table
from torch.utils._python_dispatch import TorchDispatchMode

from labcli.envs.env import LabVecEnv
from labcli.envs.random import EnvRandom
from labcli.gym import make_env

RANDOM = {"uniform_", "normal_", "random_", "exponential_", "bernoulli_"}
# No kernel: metadata, allocations, and a tensor made from host data.
NO_KERNEL = {"empty", "empty_like", "empty_strided", "new_empty", "lift_fresh", "set_",
             "_local_scalar_dense"}


class OpCount(TorchDispatchMode):
    def __init__(self):
        super().__init__()
        self.ops: collections.Counter[str] = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        name = func.overloadpacket.__name__
        if not func.is_view and name not in NO_KERNEL:
            self.ops[name] += 1
        return func(*args, **(kwargs or {}))


def count(task: str, num_envs: int, steps: int, blocks: int) -> collections.Counter[str]:
    # The step as a GPU runs it: the CPU's shortcuts (reading masks on the host) off, as the
    # env decides when it is built.
    with mock.patch.object(LabVecEnv, "_reads_on_the_host", lambda self: False):
        env = make_env(task, num_envs=num_envs, seed=0)
    env.rng = env.task.rng = EnvRandom(num_envs, "cpu", reads_masks=False, blocks=blocks)
    env.rng.manual_seed(0)
    gen = torch.Generator().manual_seed(0)
    shape = env.action_space.shape
    env.reset(seed=0)
    for _ in range(3):  # first-use set-up, as the GPU's eager steps before the capture
        env.step(torch.rand(shape, generator=gen) * 2 - 1)
    actions = [torch.rand(shape, generator=gen) * 2 - 1 for _ in range(steps)]
    with OpCount() as counter:
        for a in actions:
            env.step(a)
    env.close()
    return counter.ops


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default="g1-flat,go1-flat,go1-rough,yam-lift,panda-lift")
    p.add_argument("--num-envs", type=int, default=32)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--blocks", type=int, default=1)
    p.add_argument("--top", type=int, default=8)
    args = p.parse_args()
    table = Table("task", "ops an env step", "random draws", "the most frequent",
                  title=f"env step as a GPU runs it, {args.blocks} generator block(s)")
    for task in args.tasks.split(","):
        ops = count(task, args.num_envs, args.steps, args.blocks)
        per_step = {name: n / args.steps for name, n in ops.items()}
        top = sorted(per_step.items(), key=lambda kv: -kv[1])[:args.top]
        table.add_row(task, f"{sum(per_step.values()):.0f}",
                      f"{sum(n for k, n in per_step.items() if k in RANDOM):.0f}",
                      ", ".join(f"{k} {n:.0f}" for k, n in top))
    Console().print(table)


if __name__ == "__main__":
    main()
