"""Where a step of the cpu backend's env shards goes on many cores, beside raw `mujoco.rollout`
on as many threads (`lab bench`'s protocol, `labcli.runs.bench.beside_rollout`): when all physics
was done, how long the slowest shard's torch code ran after its physics, what one shard's took,
and the caller's part after the last shard.

  python bench/trace_shards.py [--tasks cartpole] [--envs 1024] [--threads 4,8,16]
                               [--seconds 1.5] [--repeats 2]

Every process writes the times of its step's parts into shared memory (`time.perf_counter`, one
clock for all processes); the figures are medians over the steps of a run, µs from the caller's
start of the step. Each repeat prints its own row: on a shared host the figures move between
runs, and the spread is part of what this shows. The tracing wraps private parts of
`labcli.envs.shards` and `labcli.envs.sim.chunks` and moves with them: a diagnostic, not an API.
"""

from __future__ import annotations

import argparse
import importlib
import itertools
import time
from typing import Any

import numpy as np
import torch
from rich.console import Console
from rich.table import Table

from labcli.envs import shards
from labcli.envs.env import LabVecEnv
from labcli.envs.shards import ShardedVecEnv
from labcli.envs.sim import chunks
from labcli.plugins import registry
from labcli.runs.bench import beside_rollout

RING = 16384  # steps kept per process (past it, a run's first ones are overwritten)
# A step's columns per process: its step began, its own physics was done, its step ended.
BEGAN, PHYSICS, ENDED = 0, 1, 2
SKIP = 100  # the first steps of a run, left out (the workers' first wake-ups)

_UNTRACED = {"serve": shards._serve, "buffers": shards._buffers,
             "end_init": shards._ShardEnd.__init__, "end_step": shards._ShardEnd.step,
             "physics": chunks.ChunkStepper.step}
_process: dict[str, Any] = {}  # this process's rows of the trace


def _buffers(env: LabVecEnv, num_envs: int, count: int) -> dict[str, torch.Tensor]:
    buffers = _UNTRACED["buffers"](env, num_envs, count)
    buffers["trace"] = torch.zeros(RING, count, 3, dtype=torch.float64).share_memory_()
    buffers["trace_steps"] = torch.zeros(count, dtype=torch.long).share_memory_()
    return buffers


def _end_init(self, env, buffers, shard, index) -> None:
    _UNTRACED["end_init"](self, env, buffers, shard, index)
    _process.update(trace=buffers["trace"].numpy(), steps=buffers["trace_steps"].numpy(),
                    index=index)


def _row() -> np.ndarray:
    index = _process["index"]
    trace = _process["trace"]  # its length, not RING: the process that made it read RING
    return trace[_process["steps"][index] % len(trace), index]


def _end_step(self) -> None:
    _row()[BEGAN] = time.perf_counter()
    _UNTRACED["end_step"](self)
    _row()[ENDED] = time.perf_counter()
    _process["steps"][_process["index"]] += 1


def _physics(self) -> None:
    _UNTRACED["physics"](self)
    _row()[PHYSICS] = time.perf_counter()


def _wrap() -> None:
    shards._ShardEnd.__init__ = _end_init
    shards._ShardEnd.step = _end_step
    chunks.ChunkStepper.step = _physics


def _serve(*args: Any) -> None:
    """A worker process's `_serve`, traced (a spawned process imports lab anew)."""
    _wrap()
    _UNTRACED["serve"](*args)


def install() -> None:
    """Trace every `ShardedVecEnv` made from now on, in this process and its workers. Call it on
    this module as imported by name (not as `__main__`): workers unpickle `_serve` by it."""
    _wrap()
    shards._buffers, shards._serve = _buffers, _serve


def traced_rates(env: ShardedVecEnv, reference: LabVecEnv,
                 seconds: float) -> dict[str, float]:
    """`lab bench`'s rates (`beside_rollout`), every step of the env timed in the caller too;
    the rates and the medians of the step's parts."""
    caller: list[tuple[float, float]] = []
    untimed = env.step

    def step(actions: torch.Tensor):
        began = time.perf_counter()
        out = untimed(actions)
        caller.append((began, time.perf_counter()))
        return out

    env.step = step
    lab, pool = beside_rollout(env, reference, seconds)
    # Step i is in row i % rows: past that many steps only the last ones are there.
    rows = env._buffers["trace"].numpy()
    first = max(SKIP, len(caller) - len(rows))
    trace = rows[np.arange(first, len(caller)) % len(rows)]
    began, ended = (np.array(c) for c in zip(*caller[first:], strict=True))
    physics_done = trace[:, :, PHYSICS].max(axis=1) - began
    torch_code = trace[:, :, ENDED] - trace[:, :, PHYSICS]

    def us(values: np.ndarray) -> float:
        return float(np.median(values) * 1e6)

    return {"lab": lab, "rollout": pool, "physics": us(physics_done),
            "slowest": us(torch_code.max(axis=1)),
            "shard": float(np.median(np.median(torch_code, axis=0)) * 1e6),
            "caller": us(ended - trace[:, :, ENDED].max(axis=1)), "step": us(ended - began)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default="cartpole")
    p.add_argument("--envs", default="1024")
    p.add_argument("--threads", default="4,8,16")
    p.add_argument("--seconds", type=float, default=1.5)
    p.add_argument("--repeats", type=int, default=2)
    a = p.parse_args()
    importlib.import_module("trace_shards").install()
    console = Console(width=150)
    table = Table(title="a step of env shards, medians over its steps in µs: all physics done "
                        "(from the step's start), the slowest shard's torch code after its own "
                        "physics, one shard's, the caller's part after the last shard, the step")
    for col in ("repeat", "task", "threads", "N", "lab", "rollout", "lab / rollout",
                "physics done", "slowest torch", "shard torch", "caller", "step"):
        table.add_column(col, justify="left" if col == "task" else "right")
    for repeat, task, n, threads in itertools.product(
            range(1, a.repeats + 1), a.tasks.split(","), map(int, a.envs.split(",")),
            map(int, a.threads.split(","))):
        spec = registry.get_task(task)
        cfg = spec.config_class(num_envs=n, threads=threads)
        env, reference = ShardedVecEnv(spec, cfg, seed=0), LabVecEnv(spec, cfg, backend="cpu")
        try:
            f = traced_rates(env, reference, a.seconds)
        finally:
            env.close()
            reference.close()
        table.add_row(str(repeat), task, str(threads), f"{n:,}", f"{f['lab']:,.0f}",
                      f"{f['rollout']:,.0f}", f"{f['lab'] / f['rollout']:.2f}",
                      *(f"{f[k]:,.0f}" for k in ("physics", "slowest", "shard", "caller",
                                                 "step")))
        console.print(f"  done: repeat {repeat}, {task}, {threads} threads, {n:,} envs",
                      highlight=False)
    console.print(table)


if __name__ == "__main__":
    main()
