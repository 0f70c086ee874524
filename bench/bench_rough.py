"""Rough terrain on the GPU: what the terrain and the height scan cost, and how far and how soon
`go1-rough` climbs the curriculum.

  python bench/bench_rough.py steps [--envs 4096] [--seconds 5]
  python bench/bench_rough.py train [--task go1-rough] [--logs DIR] [--seconds S] [-- ARGS...]
  python bench/bench_rough.py report RUN_DIR [--level 6] [--success 0.8] [--mjlab-log FILE]
  python bench/bench_rough.py climb RUN_DIR [--envs 16] [--steps 400] [--speed 0.8]

- steps: env-steps/s (random actions, resets included, `lab bench`'s rows) of go1-flat,
  go1-rough and go1-rough without its height scan, on the warp backend; the scan's share of
  the rough step and the rough step against the flat one.
- train: `lab train --task TASK --framework rsl_rl --backend warp ARGS` as a user runs it, in
  DIR (a fresh temporary one unless given); a run DIR already holds is resumed
  (`--checkpoint latest`), so that a training longer than one sitting goes on where it
  stopped; --seconds stops it by SIGINT (it saves and exits). Then the report of its run.
- report: from a run's TensorBoard events, per events file (a resumed run has one per
  sitting, the pause between them not counted): seconds of training until the mean terrain
  level (`Metrics/terrain/level`, the row: 0 to 9) and the success rate were first both at
  least --level and --success, their values after 5, 10 and 15 minutes and at the end, and the
  median training steps/s, and at the end the level per terrain type and the share of
  episodes each termination ended; with --mjlab-log, a console log of mjlab's own `train`
  (RSL-RL's "Steps per second" lines) run in the same machine start, and the ratio to its
  median.
- climb: a trained run's policy on the CPU, as `lab play` runs it (noise and pushes off), on
  each pyramid alone (stairs and slopes, up out of the pit where inverted, else down from the
  platform), band by band of difficulty: each robot starts at its patch's centre and is
  commanded straight ahead at --speed; how many reached the patch's edge (the whole flight or
  slope behind them) before a fall, how many fell, and how far they walked.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from labcli.envs import metrics
from labcli.runs.bench import bench

MARKS_MIN = (5, 10, 15)


def steps(envs: int, seconds: float) -> None:
    variants = {"go1-flat": ("go1-flat", []), "go1-rough": ("go1-rough", []),
                "go1-rough, no scan": ("go1-rough", ["env.observations.height_scan=null"])}
    rates = {}
    for name, (task, overrides) in variants.items():
        (row,) = bench(task, [envs], backend="warp", seconds=seconds, overrides=overrides)
        rates[name] = row.env_steps_per_s
        print(f"{name}: {rates[name]:,.0f} env-steps/s at {envs} envs", flush=True)
    scan = 1 - rates["go1-rough"] / rates["go1-rough, no scan"]
    print(f"height scan: {100 * scan:.1f}% of the rough step; rough against flat: "
          f"{rates['go1-rough'] / rates['go1-flat']:.2f}×")


def train(task: str, logs: Path, seconds: float | None, args: list[str]) -> Path:
    runs = Path(logs, "rsl_rl", task)
    resume = ["--checkpoint", "latest"] if runs.is_dir() and any(runs.iterdir()) else []
    cmd = ["lab", "train", "--task", task, "--framework", "rsl_rl", "--backend", "warp",
           *resume, *args]
    print(" ".join(cmd), flush=True)
    child = subprocess.Popen(cmd, env={**os.environ, "LAB_LOGS_DIR": str(logs)})
    try:
        if child.wait(timeout=seconds) != 0:
            sys.exit(f"lab train ended with exit code {child.returncode}: nothing to report")
    except subprocess.TimeoutExpired:
        child.send_signal(signal.SIGINT)
        child.wait()
    return sorted(runs.iterdir())[-1]


def sittings(run_dir: Path) -> list[dict[str, list[tuple[float, int, float]]]]:
    """Per events file, in order: each tag's (seconds since the file's first event, step,
    value)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = []
    for path in sorted(run_dir.glob("events.out.tfevents.*"), key=lambda p: p.stat().st_mtime):
        events = EventAccumulator(str(path), size_guidance={"scalars": 0})
        events.Reload()
        start = events.FirstEventTimestamp()
        out.append({tag: [(s.wall_time - start, s.step, s.value) for s in events.Scalars(tag)]
                    for tag in events.Tags()["scalars"]})
    return out


def joined(parts: list[dict], tag: str) -> list[tuple[float, int, float]]:
    """One tag over the sittings, the seconds of each after those of the ones before it."""
    out, offset = [], 0.0
    for part in parts:
        rows = part.get(tag, [])
        out += [(offset + t, step, value) for t, step, value in rows]
        if part:
            offset += max(t for rows in part.values() for t, _, _ in rows)
    return out


def at(series: list[tuple[float, int, float]], seconds: float) -> float | None:
    before = [value for t, _, value in series if t <= seconds]
    return before[-1] if before else None


def last_values(parts: list[dict], prefix: str) -> dict[str, float]:
    """The last value of every tag under `prefix`, by the rest of its name."""
    tags = sorted({tag for part in parts for tag in part if tag.startswith(prefix)})
    return {tag.removeprefix(prefix): joined(parts, tag)[-1][2] for tag in tags}


def report(run_dir: Path, level: float, success: float, mjlab_log: Path | None) -> dict:
    parts = sittings(run_dir)
    levels, successes = joined(parts, metrics.TERRAIN_LEVEL), joined(parts, metrics.SUCCESS_RATE)
    by_step = {step: value for _, step, value in successes}
    reached = next(((t, step) for t, step, value in levels
                    if value >= level and by_step.get(step, 0.0) >= success), None)
    rates = [value for _, _, value in joined(parts, metrics.STEPS_PER_S)[2:]]
    row = {"run": str(run_dir), "sittings": len(parts),
           "training_s": levels[-1][0] if levels else None,
           "steps_per_s": statistics.median(rates) if rates else None,
           "reached_s": reached[0] if reached else None,
           "reached_steps": reached[1] if reached else None,
           "marks": {m: (at(levels, 60 * m), at(successes, 60 * m)) for m in MARKS_MIN},
           "final": (levels[-1][2] if levels else None,
                     successes[-1][2] if successes else None),
           # Where the mean hides it: each terrain type's level, and what ended the episodes.
           "final_by_type": last_values(parts, metrics.TERRAIN_LEVEL + "/"),
           "final_ends": last_values(parts, metrics.TERMINATION)}
    print(f"{run_dir}: {row['sittings']} sitting(s), {row['training_s'] or 0:.0f} s of "
          f"training, {row['steps_per_s'] or 0:,.0f} steps/s")
    when = (f"after {row['reached_s']:.0f} s ({row['reached_steps']:,} steps)"
            if reached else "never")
    print(f"mean level >= {level} with success >= {success}: {when}")
    for m, (lv, sr) in row["marks"].items():
        if lv is not None:
            print(f"after {m} min: mean level {lv:.2f}, success {sr:.2f}")
    if None in row["final"]:
        print("at the end: no terrain level and success logged")
    else:
        print(f"at the end: mean level {row['final'][0]:.2f}, success {row['final'][1]:.2f}")
    if row["final_by_type"]:
        print("  levels: " + ", ".join(f"{k} {v:.1f}" for k, v in row["final_by_type"].items()))
    if row["final_ends"]:
        print("  episodes ended by: " + ", ".join(f"{k} {v:.0%}"
                                                  for k, v in row["final_ends"].items()))
    if mjlab_log is not None:
        theirs = [float(x) for x in re.findall(r"Steps per second:\s*([\d.]+)",
                                               mjlab_log.read_text(errors="replace"))]
        row["mjlab_steps_per_s"] = statistics.median(theirs[1:] or theirs) if theirs else None
        if row["mjlab_steps_per_s"] and row["steps_per_s"]:
            print(f"mjlab: {row['mjlab_steps_per_s']:,.0f} steps/s; lab "
                  f"{row['steps_per_s'] / row['mjlab_steps_per_s']:.2f}× it")
    return row


# The pyramids, from the patch's centre: which way a robot walks to the patch's edge.
PYRAMIDS = {"stairs_down": "up out of the pit", "stairs": "down from the platform",
            "slope_down": "up out of the pit", "slope": "down from the top"}
BANDS = ((0.0, 0.3), (0.3, 0.6), (0.6, 0.8), (0.8, 1.0))
EDGE = 0.15  # m inside the patch's edge: on the outermost tread


def climb(run_dir: Path, envs: int, steps: int, speed: float) -> list[dict]:
    import torch

    from labcli.runs import play, rundir

    command = "env.commands.base_velocity"
    straight = [f"{command}.rel_heading_envs=0", f"{command}.rel_standing_envs=0",
                f"{command}.lin_vel_x=[{speed},{speed}]", f"{command}.lin_vel_y=[0,0]",
                f"{command}.ang_vel_z=[0,0]"]
    types = rundir.open_run(run_dir).params(rundir.ENV_PARAMS)["terrain"]["types"]
    rows = []
    for kind, way in PYRAMIDS.items():
        if types.get(kind) is None:
            continue
        alone = [f"env.terrain.types.{other}=null" for other in types if other != kind]
        for low, high in BANDS:
            loaded = play.load(run_dir=run_dir, num_envs=envs, seed=1, overrides=[
                *alone, *straight, f"env.terrain.difficulty=[{low},{high}]"])
            env, task = loaded.env, loaded.env.task
            try:
                obs, _ = env.reset(seed=1)
                grid = task.terrain
                centre = grid.origins[grid.levels, grid.types][:, :2]
                start = task.robot.root_xy.clone()
                crossed = torch.zeros(envs, dtype=torch.bool)
                fell = torch.zeros(envs, dtype=torch.bool)
                ended = torch.zeros(envs, dtype=torch.bool)  # a fall, after crossing or not
                walked = torch.zeros(envs)
                with torch.no_grad():
                    for _ in range(steps):
                        obs, _, terminated, _, _ = env.step(loaded.policy(obs))
                        fell |= terminated & ~crossed
                        ended |= terminated
                        xy = task.robot.root_xy
                        reach = (xy - centre).abs().amax(dim=1)
                        crossed |= ~ended & (reach >= grid.cfg.size / 2 - EDGE)
                        walked = torch.where(ended, walked,
                                             torch.linalg.vector_norm(xy - start, dim=1))
            finally:
                env.close()
            row = {"terrain": kind, "difficulty": [low, high], "robots": envs,
                   "crossed": int(crossed.sum()), "fell": int(fell.sum()),
                   "walked_m_median": float(walked.median())}
            rows.append(row)
            print(f"{kind} ({way}), difficulty {low}-{high} ({_extent(types[kind], low, high)}"
                  f"): {row['crossed']} of {envs} reached the patch's edge, {row['fell']} fell "
                  f"(median {row['walked_m_median']:.1f} m walked in {steps} steps)", flush=True)
    return rows


def _extent(terrain: dict, low: float, high: float) -> str:
    """What the band's difficulties make of a pyramid: its steps' height or its slope."""
    key, unit = ("step_height", " m steps") if "step_height" in terrain else ("slope", " slope")
    first, last = terrain[key]
    return f"{first + low * (last - first):.2f}-{first + high * (last - first):.2f}{unit}"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="action", required=True)
    s = sub.add_parser("steps")
    s.add_argument("--envs", type=int, default=4096)
    s.add_argument("--seconds", type=float, default=5.0)
    t = sub.add_parser("train")
    t.add_argument("--task", default="go1-rough")
    t.add_argument("--logs", type=Path)
    t.add_argument("--seconds", type=float)
    t.add_argument("args", nargs="*", help="more `lab train` arguments, after --")
    r = sub.add_parser("report")
    r.add_argument("run_dir", type=Path)
    for q in (t, r):
        q.add_argument("--level", type=float, default=6.0)
        q.add_argument("--success", type=float, default=0.8)
        q.add_argument("--mjlab-log", type=Path)
        q.add_argument("--json", type=Path, help="write the report here")
    c = sub.add_parser("climb")
    c.add_argument("run_dir", type=Path)
    c.add_argument("--envs", type=int, default=16)
    c.add_argument("--steps", type=int, default=400)
    c.add_argument("--speed", type=float, default=0.8)
    c.add_argument("--json", type=Path, help="write the rows here")
    a = p.parse_args()
    if a.action == "steps":
        steps(a.envs, a.seconds)
        return
    if a.action == "climb":
        rows = climb(a.run_dir, a.envs, a.steps, a.speed)
        if a.json:
            a.json.write_text(json.dumps(rows, indent=1))
        return
    with tempfile.TemporaryDirectory(prefix="bench_rough_") as scratch:
        run_dir = (train(a.task, a.logs or Path(scratch), a.seconds, a.args)
                   if a.action == "train" else a.run_dir)
        row = report(run_dir, a.level, a.success, a.mjlab_log)
    if a.json:
        a.json.write_text(json.dumps(row, indent=1))


if __name__ == "__main__":
    main()
