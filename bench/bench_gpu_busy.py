"""Where a GPU training iteration's time goes: the GPU's own kernel time beside the wall time,
and the host's reads of the GPU, over iterations of `lab train --backend warp`.

  python bench/bench_gpu_busy.py [--task g1-flat] [--framework rsl_rl] [--num-envs 4096]
                                 [--warmup 20] [--iterations 10] [--top 12]

An iteration cannot take less than its kernels' time on the GPU; what it takes beyond that is
the GPU idle: waiting for the host's launches; after each read of the GPU (`.item()`, `if
tensor`, a copy to the host), which waits for all the work queued so far, while the host
launches the next; or between its own short kernels, each of which costs it microseconds to
start, in a CUDA graph too (then the host is ahead: its launches wait on "Command Buffer
Full"). Printed per iteration: the wall seconds (the iterations before the profiled ones,
without the profiler's cost), the kernels' seconds and their share of the wall time, the host's
reads of the GPU and its waits, then the kernels and host ops that took the most time. Needs
CUDA.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import torch
from torch.profiler import ProfilerActivity, profile

from labcli.runs.training import train

# Host calls that wait for the GPU: each read of a value (`.item()`, `bool(tensor)`) goes
# through `aten::_local_scalar_dense`; the waits themselves are CUDA runtime calls.
READS = "aten::_local_scalar_dense"
WAITS = ("cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaEventSynchronize")


def device_us(event: Any) -> float:
    return event.self_device_time_total


def measure(task: str, framework: str, num_envs: int | None, warmup: int,
            iterations: int) -> tuple[list[float], Any]:
    """Wall seconds between iteration ends up to `warmup`, and the profiler of the
    `iterations` after it."""
    ends: list[float] = []
    state: dict[str, Any] = {}

    def hook(iteration: int, steps: int, figures: dict[str, float]) -> bool:
        ends.append(time.perf_counter())
        if iteration == warmup:
            torch.cuda.synchronize()
            state["prof"] = profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA])
            state["prof"].__enter__()
        elif iteration == warmup + iterations:
            torch.cuda.synchronize()
            state["prof"].__exit__(None, None, None)
            return True  # stop the run as Ctrl-C would
        return False

    with tempfile.TemporaryDirectory(prefix="bench_gpu_busy_") as logs:
        train(task, framework, backend="warp", num_envs=num_envs, logs_dir=Path(logs),
              max_iterations=warmup + iterations + 1, on_iteration=hook)
    if "prof" not in state:
        sys.exit(f"error: the run ended before iteration {warmup + iterations}")
    # ends[i] is iteration i + 1's: the deltas of iterations 2 to `warmup`, the later half
    walls = [b - a for a, b in zip(ends[:warmup - 1], ends[1:warmup], strict=True)]
    return walls[len(walls) // 2:], state["prof"]


def report(walls: list[float], prof: Any, iterations: int, top: int) -> None:
    events = prof.key_averages()
    wall = statistics.median(walls)
    kernels = sum(device_us(e) for e in events) / 1e6 / iterations
    reads = sum(e.count for e in events if e.key == READS) / iterations
    waits = sum(e.cpu_time_total for e in events if e.key in WAITS) / 1e6 / iterations
    print(f"per iteration: {wall:.3f} s of wall time (median of {len(walls)} unprofiled), "
          f"{kernels:.3f} s of kernels on the GPU ({kernels / wall:.0%} busy); "
          f"{reads:.0f} reads of the GPU by the host, {waits:.3f} s of host waits (profiled)")
    print(f"\nkernels, ms per iteration (of {kernels * 1e3:.1f}):")
    for e in sorted(events, key=device_us, reverse=True)[:top]:
        print(f"  {device_us(e) / 1e3 / iterations:8.2f}  {e.count / iterations:7.1f} calls  "
              f"{e.key[:90]}")
    print("\nhost ops, own ms per iteration (profiled):")
    for e in sorted(events, key=lambda e: e.self_cpu_time_total, reverse=True)[:top]:
        print(f"  {e.self_cpu_time_total / 1e3 / iterations:8.2f}  {e.count / iterations:7.1f}"
              f" calls  {e.key[:90]}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="g1-flat")
    p.add_argument("--framework", default="rsl_rl")
    p.add_argument("--num-envs", type=int, help="the task's GPU default unless given")
    p.add_argument("--warmup", type=int, default=20, help="iterations before the profiled ones")
    p.add_argument("--iterations", type=int, default=10, help="iterations profiled")
    p.add_argument("--top", type=int, default=12, help="rows of each table")
    a = p.parse_args()
    if not torch.cuda.is_available():
        print("error: bench_gpu_busy.py profiles GPU training, and torch sees no CUDA GPU here "
              "(run it on a machine with one and lab's warp backend installed)", file=sys.stderr)
        sys.exit(2)
    if a.warmup < 4 or a.iterations < 1:
        print("error: --warmup must be at least 4 and --iterations at least 1", file=sys.stderr)
        sys.exit(2)
    print(f"{a.task}, {a.framework}, {torch.cuda.get_device_name()}, torch {torch.__version__}")
    walls, prof = measure(a.task, a.framework, a.num_envs, a.warmup, a.iterations)
    report(walls, prof, a.iterations, a.top)


if __name__ == "__main__":
    main()
