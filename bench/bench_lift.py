"""yam-lift beside mjlab's Mjlab-Lift-Cube-Yam, from the TensorBoard events of a run of each made
in the same machine start:

  lab train --task yam-lift --framework rsl_rl --backend warp                    # lab
  train Mjlab-Lift-Cube-Yam --env.scene.num-envs 4096 --agent.logger tensorboard  # mjlab 1.6.0
  python bench/bench_lift.py LAB_RUN_DIR [MJLAB_RUN_DIR] [--mjlab-envs 4096] [--at STEPS]
                             [--json FILE]

Prints each one's median training steps/s (the first two iterations, compilation and warm-up,
left out) and lab's ratio to mjlab's (the goal: 3×); then two measures of success, each the
same on both sides: at the episode's end, the cube within 5 cm of its last target (lab's
success rate, mjlab's `at_goal`) and at any step since that target was drawn (lab's
`reached`, mjlab's latched `episode_success`); for each, the steps after which it first
reached 0.1, 0.5 and 0.7, and its value, with the cube's distance to its target, at the steps
the shorter run reached (or at `--at`: a run of lab beside one of mjlab measured before,
e.g. its last step). Without mjlab's run, lab's figures alone. A run resumed over several
sittings reads as one.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from bench_rough import joined, sittings

from labcli.envs import metrics

# Each measure's tags: (lab's, mjlab's).
TAGS = {"steps_per_s": (metrics.STEPS_PER_S, "Perf/total_fps"),
        "success": (metrics.SUCCESS_RATE, "Metrics/lift_height/at_goal"),
        "reached": ("Metrics/lift_height/reached", "Metrics/lift_height/episode_success"),
        "error": ("Metrics/lift_height/position_error", "Metrics/lift_height/position_error")}
LEVELS = (0.1, 0.5, 0.7)
STEPS_PER_ENV = 24  # both agents' rollout: mjlab logs by iteration, lab by env step


def _median_rate(series: list[tuple[float, int, float]]) -> float | None:
    rates = [value for _, _, value in series[2:]]
    return statistics.median(rates) if rates else None


def _at_step(series: list[tuple[float, int, float]], step: int) -> float | None:
    before = [value for _, s, value in series if s <= step]
    return before[-1] if before else None


def _first_step(series: list[tuple[float, int, float]], level: float) -> int | None:
    # TensorBoard keeps float32: a logged 0.7 reads back as 0.69999999.
    return next((step for _, step, value in series if value >= level - 1e-6), None)


def _shown(value: float | None, form: str = ".3f") -> str:
    return "-" if value is None else format(value, form)


def compare(lab_run: Path, mjlab_run: Path | None, mjlab_envs: int,
            at: int | None = None) -> dict:
    series = {"lab": {key: joined(sittings(lab_run), lab) for key, (lab, _) in TAGS.items()}}
    if mjlab_run is not None:
        theirs, per_iteration = sittings(mjlab_run), mjlab_envs * STEPS_PER_ENV
        series["mjlab"] = {key: [(t, step * per_iteration, value)
                                 for t, step, value in joined(theirs, mjlab)]
                           for key, (_, mjlab) in TAGS.items()}
    common = at if at is not None else min(s["success"][-1][1] for s in series.values())
    row = {"lab_run": str(lab_run), "mjlab_run": str(mjlab_run) if mjlab_run else None,
           "common_steps": common}
    for who, own in series.items():
        row[f"{who}_steps_per_s"] = _median_rate(own["steps_per_s"])
        for key in ("success", "reached", "error"):
            row[f"{who}_{key}"] = _at_step(own[key], common)
        for key in ("success", "reached"):
            row[f"{who}_{key}_first"] = {level: _first_step(own[key], level) for level in LEVELS}
    rates = ", ".join(f"{who} {row[f'{who}_steps_per_s'] or 0:,.0f}" for who in series)
    if "mjlab" in series:
        ratio = (row["lab_steps_per_s"] / row["mjlab_steps_per_s"]
                 if row["lab_steps_per_s"] and row["mjlab_steps_per_s"] else None)
        rates += f": lab {ratio or 0:.2f}× mjlab's (goal 3×)"
        row["ratio"] = ratio
    print(f"training steps/s: {rates}")
    for key, name in (("success", "within 5 cm at the end"),
                      ("reached", "within 5 cm at any step since the target was drawn")):
        print(f"{name}:")
        for who in series:
            firsts = ", ".join(f"{level} after {_shown(step, ',')}"
                               for level, step in row[f"{who}_{key}_first"].items())
            print(f"  {who:5} {firsts} steps; {_shown(row[f'{who}_{key}'])} after {common:,}")
    errors = ", ".join(f"{who} {_shown(row[f'{who}_error'])} m" for who in series)
    print(f"the cube's distance to its target after {common:,} steps: {errors}")
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("lab_run", type=Path)
    p.add_argument("mjlab_run", type=Path, nargs="?",
                   help="a directory holding mjlab's events file(s); none: lab's figures alone")
    p.add_argument("--mjlab-envs", type=int, default=4096)
    p.add_argument("--at", type=int, help="env steps at which to read the measures (default: "
                   "the last step both runs reached)")
    p.add_argument("--json", type=Path, help="write the row here")
    a = p.parse_args()
    row = compare(a.lab_run, a.mjlab_run, a.mjlab_envs, a.at)
    if a.json:
        a.json.write_text(json.dumps(row, indent=2))


if __name__ == "__main__":
    main()
