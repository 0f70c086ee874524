"""Soak test: a long `lab train` must not grow in memory.

Starts `lab train` as its own process for `--minutes` (10 by default), samples its resident
memory (VmRSS) every `--every` seconds, then stops it with SIGINT as a user would. The growth is
measured from the first sample (after the first interval: imports, env and agent are built by
then) to the last. Exits 1 when it is `--limit` (10 %) or more, or when the run did not stop
cleanly (exit code 130, summary 'interrupted', a checkpoint).

    python bench/soak.py                       # 10 minutes of sb3 on cartpole
    python bench/soak.py --framework rsl_rl --minutes 2 --every 20
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def rss_mib(pid: int) -> float:
    """Resident memory of `pid` in MiB (Linux: /proc/<pid>/status)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for pid {pid}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--framework", default="sb3")
    parser.add_argument("--task", default="cartpole")
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--every", type=float, default=60.0, help="seconds between samples")
    parser.add_argument("--limit", type=float, default=0.10, help="largest growth allowed")
    args = parser.parse_args()

    logs = Path(tempfile.mkdtemp(prefix="lab-soak-"))
    command = [sys.executable, "-m", "labcli", "train", "--task", args.task, "--framework",
               args.framework, "--max-iterations", "100000000", "--run-name", "soak"]
    print(f"$ {' '.join(command[2:])}  (logs in {logs})", flush=True)
    proc = subprocess.Popen(command, env={**os.environ, "LAB_LOGS_DIR": str(logs)},
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    samples: list[tuple[float, float]] = []
    t0 = time.monotonic()
    try:
        for k in range(1, int(args.minutes * 60 / args.every) + 1):
            time.sleep(max(0.0, t0 + k * args.every - time.monotonic()))
            if proc.poll() is not None:
                print(f"lab train ended early with exit code {proc.returncode}")
                return 1
            samples.append((time.monotonic() - t0, rss_mib(proc.pid)))
            print(f"  {samples[-1][0]:6.0f} s  RSS {samples[-1][1]:8.1f} MiB", flush=True)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()

    first, last = samples[0][1], samples[-1][1]
    growth = (last - first) / first
    (summary_path,) = logs.glob(f"{args.framework}/{args.task}/*_soak/summary.json")
    summary = json.loads(summary_path.read_text())
    print(f"RSS {first:.1f} MiB at {samples[0][0]:.0f} s -> {last:.1f} MiB at "
          f"{samples[-1][0]:.0f} s: growth {growth:+.1%} (limit {args.limit:.0%})")
    print(f"stopped with exit code {proc.returncode}: {summary['state']}, "
          f"{summary['iterations']} iterations, {summary['steps']:,} steps, "
          f"checkpoint {summary['checkpoint']}")
    clean = proc.returncode == 130 and summary["state"] == "interrupted" \
        and summary["checkpoint"] is not None
    return 0 if growth < args.limit and clean else 1


if __name__ == "__main__":
    sys.exit(main())
