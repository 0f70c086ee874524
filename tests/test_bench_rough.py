"""bench/bench_rough.py's report, read from TensorBoard events written here: when the level and
success goal was first met, over a run resumed in two sittings, and what the mean hides."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import benchscripts
import pytest
from torch.utils.tensorboard import SummaryWriter

from labcli.envs import metrics


@pytest.fixture(scope="module")
def bench_rough():
    return benchscripts.load("bench_rough")


def sitting(run_dir: Path, start: float, rows: list[tuple[float, int, dict[str, float]]],
            monkeypatch: pytest.MonkeyPatch) -> None:
    """An events file of one sitting begun at `start` (its first event, which the writer stamps
    with the clock's time): at `start + t` s, step `step`, the scalars given."""
    with monkeypatch.context() as clock:
        clock.setattr(time, "time", lambda: start)
        writer = SummaryWriter(str(run_dir), filename_suffix=f".{start:.0f}")
    for t, step, values in rows:
        for tag, value in values.items():
            writer.add_scalar(tag, value, step, walltime=start + t)
    writer.close()


def test_the_report_joins_sittings_and_names_each_terrain_type_and_cause(tmp_path, bench_rough,
                                                                         monkeypatch):
    level, success = metrics.TERRAIN_LEVEL, metrics.SUCCESS_RATE
    stairs, rough = f"{level}/stairs", f"{level}/rough"
    falls, unstable = f"{metrics.TERMINATION}base_contact", f"{metrics.TERMINATION}unstable"
    now = time.time()
    sitting(tmp_path, now, [
        (0, 1, {level: 2.0, success: 0.0, stairs: 2.0, rough: 2.0, falls: 0.9}),
        (200, 100, {level: 4.0, success: 0.5, stairs: 5.0, rough: 3.0, falls: 0.3}),
        (400, 200, {level: 5.0, success: 0.9, stairs: 6.0, rough: 4.0, falls: 0.2}),
    ], monkeypatch)
    # Resumed an hour later: the pause is not training.
    sitting(tmp_path, now + 3600, [
        (0, 201, {level: 5.5, success: 0.85, stairs: 6.5, rough: 4.5, falls: 0.2,
                  unstable: 0.01}),
        (300, 300, {level: 6.5, success: 0.8, stairs: 7.0, rough: 6.0, falls: 0.1,
                    unstable: 0.05}),
    ], monkeypatch)
    row = bench_rough.report(tmp_path, level=6.0, success=0.8, mjlab_log=None)
    assert row["sittings"] == 2
    assert row["training_s"] == pytest.approx(700)
    assert row["reached_s"] == pytest.approx(700) and row["reached_steps"] == 300
    assert row["marks"][5] == (4.0, 0.5)  # at 300 s: the value logged at 200 s
    assert row["marks"][10] == pytest.approx((5.5, 0.85))  # at 600 s: the second sitting's first
    assert row["final"] == pytest.approx((6.5, 0.8))
    assert row["final_by_type"] == {"rough": 6.0, "stairs": 7.0}
    assert row["final_ends"] == pytest.approx({"base_contact": 0.1, "unstable": 0.05})


def test_a_training_that_fails_says_so_and_reports_nothing(tmp_path, bench_rough, monkeypatch):
    monkeypatch.setenv("PATH", f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    with pytest.raises(SystemExit, match="lab train ended with exit code 2: nothing to report"):
        bench_rough.train("no-such-task", tmp_path, 120, [])


def test_a_run_that_logged_no_level_is_reported_as_such(tmp_path, bench_rough, capsys):
    row = bench_rough.report(tmp_path, level=6.0, success=0.8, mjlab_log=None)
    assert row["final"] == (None, None) and row["reached_s"] is None
    assert "at the end: no terrain level and success logged" in capsys.readouterr().out


def test_climb_counts_the_robots_that_reach_their_patch_s_edge(tmp_path, bench_rough,
                                                               monkeypatch):
    """A go1-rough run on a small grid of the four pyramids, barely trained: in 10 steps no
    robot walks from its patch's centre to the edge 1.85 m away, so none is counted; with the
    edge moved to 0.1 m from the centre, the robots that the reset placed beyond it are."""
    import io
    import json

    from rich.console import Console

    from labcli.runs import training

    pyramid = {"platform": 1.0, "step_width": 0.3}
    types = {"stairs": {"type": "pyramid_stairs", **pyramid},
             "stairs_down": {"type": "pyramid_stairs", "inverted": True, **pyramid},
             "slope": {"type": "pyramid_slope", "platform": 1.0},
             "slope_down": {"type": "pyramid_slope", "platform": 1.0, "inverted": True},
             "boxes": None, "rough": None}
    terrain = {"size": 4.0, "rows": 2, "cols": 4, "border": 1.0, "types": types}
    run = training.train("go1-rough", "rsl_rl", num_envs=4, max_iterations=1, logs_dir=tmp_path,
                         console=Console(file=io.StringIO()), command=["lab", "test"],
                         overrides=["env.terrain=" + json.dumps(terrain),
                                    "agent.num_steps_per_env=4"]).run
    rows = bench_rough.climb(run.dir, envs=4, steps=10, speed=0.8)
    assert [(r["terrain"], tuple(r["difficulty"])) for r in rows] == [
        (kind, band) for kind in bench_rough.PYRAMIDS for band in bench_rough.BANDS]
    assert all(r["crossed"] == 0 and 0 <= r["fell"] <= 4 and r["walked_m_median"] < 1.0
               for r in rows)

    monkeypatch.setattr(bench_rough, "PYRAMIDS", {"stairs_down": "up out of the pit"})
    monkeypatch.setattr(bench_rough, "EDGE", 1.9)
    rows = bench_rough.climb(run.dir, envs=4, steps=1, speed=0.8)
    assert len(rows) == len(bench_rough.BANDS) and all(r["crossed"] >= 1 for r in rows)
