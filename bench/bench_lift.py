"""yam-lift beside mjlab's Mjlab-Lift-Cube-Yam, from the TensorBoard events of a run of each made
in the same machine start:

  lab train --task yam-lift --framework rsl_rl --backend warp                    # lab
  train Mjlab-Lift-Cube-Yam --env.scene.num-envs 4096 --agent.logger tensorboard  # mjlab 1.6.0
  python bench/bench_lift.py LAB_RUN_DIR MJLAB_RUN_DIR [--mjlab-envs 4096] [--json FILE]

Prints each one's median training steps/s (the first two iterations, compilation and warm-up,
left out) and lab's ratio to mjlab's (the goal: 3×); then, at the steps the shorter run
reached, each one's success and the cube's distance to its target: lab's success rate of the
episodes ended then (the cube within 5 cm of the last target at the time-out) and mjlab's
latched `episode_success` (within 5 cm at any moment since the last target), which are not the
same measure, and both position errors. A run resumed over several sittings reads as one.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from bench_rough import joined, sittings

from labcli.envs import metrics

LAB_ERROR = "Metrics/lift_height/position_error"
MJLAB = {"steps_per_s": "Perf/total_fps", "success": "Metrics/lift_height/episode_success",
         "error": "Metrics/lift_height/position_error"}
STEPS_PER_ENV = 24  # both agents' rollout: mjlab logs by iteration, lab by env step


def _median_rate(series: list[tuple[float, int, float]]) -> float | None:
    rates = [value for _, _, value in series[2:]]
    return statistics.median(rates) if rates else None


def _at_step(series: list[tuple[float, int, float]], step: int) -> float | None:
    before = [value for _, s, value in series if s <= step]
    return before[-1] if before else None


def _shown(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def compare(lab_run: Path, mjlab_run: Path, mjlab_envs: int) -> dict:
    ours, theirs = sittings(lab_run), sittings(mjlab_run)
    per_iteration = mjlab_envs * STEPS_PER_ENV
    mjlab = {key: [(t, step * per_iteration, value) for t, step, value in joined(theirs, tag)]
             for key, tag in MJLAB.items()}
    lab = {"steps_per_s": joined(ours, metrics.STEPS_PER_S),
           "success": joined(ours, metrics.SUCCESS_RATE), "error": joined(ours, LAB_ERROR)}
    common = min(lab["success"][-1][1], mjlab["success"][-1][1])
    row = {"lab_run": str(lab_run), "mjlab_run": str(mjlab_run), "common_steps": common,
           **{f"{who}_{key}": (_median_rate(series[key]) if key == "steps_per_s"
                               else _at_step(series[key], common))
              for who, series in (("lab", lab), ("mjlab", mjlab)) for key in MJLAB}}
    ratio = (row["lab_steps_per_s"] / row["mjlab_steps_per_s"]
             if row["lab_steps_per_s"] and row["mjlab_steps_per_s"] else None)
    row["ratio"] = ratio
    print(f"training steps/s: lab {row['lab_steps_per_s'] or 0:,.0f}, mjlab "
          f"{row['mjlab_steps_per_s'] or 0:,.0f}: lab {ratio or 0:.2f}× mjlab's (goal 3×)")
    print(f"after {common:,} steps: lab success {_shown(row['lab_success'])}, cube "
          f"{_shown(row['lab_error'])} m from its target; mjlab episode_success "
          f"{_shown(row['mjlab_success'])}, cube {_shown(row['mjlab_error'])} m from its target")
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("lab_run", type=Path)
    p.add_argument("mjlab_run", type=Path, help="a directory holding mjlab's events file(s)")
    p.add_argument("--mjlab-envs", type=int, default=4096)
    p.add_argument("--json", type=Path, help="write the row here")
    a = p.parse_args()
    row = compare(a.lab_run, a.mjlab_run, a.mjlab_envs)
    if a.json:
        a.json.write_text(json.dumps(row, indent=2))


if __name__ == "__main__":
    main()
