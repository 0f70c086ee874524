"""How fast `lab` answers: seconds from Enter to exit (or, for `lab train`, to its first line) for
the commands people type most and for shell completion, as medians of repeated runs, beside
the floor of any Python program and the price of importing torch, measured in the same run.

    python bench/bench_startup.py [--repeat 15] [--json]

Goals (issue 14): --version, --help and a completion <= 0.3 s; list, runs and config show
<= 1.0 s; lab train's first line <= 1.5 s after Enter.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LAB = shutil.which("lab") or "lab"
# name -> (argv, extra environment, goal in seconds); None: a reference, no goal.
COMPLETE = {"_LAB_COMPLETE": "complete_bash", "COMP_WORDS": "lab train --task ca",
            "COMP_CWORD": "3"}
CASES = {
    "python -c pass": ([sys.executable, "-c", "pass"], {}, None),
    "python -c 'import torch'": ([sys.executable, "-c", "import torch"], {}, None),
    "lab --version": ([LAB, "--version"], {}, 0.3),
    "lab --help": ([LAB, "--help"], {}, 0.3),
    "completion of --task": ([LAB], COMPLETE, 0.3),
    "lab list": ([LAB, "list"], {}, 1.0),
    "lab runs": ([LAB, "runs"], {}, 1.0),
    "lab config show": ([LAB, "config", "show", "--task", "cartpole", "--framework", "sb3"], {},
                        1.0),
}
TRAIN = ([LAB, "train", "--task", "cartpole", "--framework", "rsl_rl", "--max-iterations", "1"],
         {}, 1.5)


def until_exit(argv: list[str], env: dict[str, str]) -> float:
    start = time.perf_counter()
    subprocess.run(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                   check=True)
    return time.perf_counter() - start


def until_first_line(argv: list[str], env: dict[str, str]) -> float:
    """Seconds until the process writes its first line on stderr; then it is stopped."""
    start = time.perf_counter()
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        line = proc.stderr.readline()
        seconds = time.perf_counter() - start
    finally:
        proc.kill()
        proc.wait()
    if not line:
        raise RuntimeError(f"{' '.join(argv)} wrote nothing on stderr")
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="lab_startup_") as logs:
        env = {**os.environ, "LAB_LOGS_DIR": logs}
        for name, (argv, extra, goal) in [*CASES.items(), ("lab train: first line", TRAIN)]:
            timer = until_first_line if name.startswith("lab train") else until_exit
            times = [timer(argv, {**env, **extra}) for _ in range(args.repeat)]
            rows.append({"case": name, "median_s": statistics.median(times),
                         "min_s": min(times), "max_s": max(times), "goal_s": goal})
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    print(f"{'case':<28} {'median s':>9} {'min':>7} {'max':>7} {'goal':>6}  met")
    for row in rows:
        goal = row["goal_s"]
        met = "" if goal is None else ("yes" if row["median_s"] <= goal else "NO")
        print(f"{row['case']:<28} {row['median_s']:>9.3f} {row['min_s']:>7.3f} "
              f"{row['max_s']:>7.3f} {'' if goal is None else goal:>6}  {met}")
    print(f"({args.repeat} runs each; {Path(LAB)}; Python {sys.version.split()[0]})")


if __name__ == "__main__":
    main()
