"""bench/bench_lift.py's comparison, read from TensorBoard events written here: mjlab's steps
are iterations of 24 steps per env, each side's measures are paired like for like, and the
values compared are those at the steps both runs reached; lab's run alone at the steps asked."""

from __future__ import annotations

import benchscripts
import pytest
from torch.utils.tensorboard import SummaryWriter

from labcli.envs import metrics

ENVS = 4
ITERATION = ENVS * 24  # env steps an iteration


def events(run_dir, rows: list[tuple[int, dict[str, float]]]) -> None:
    writer = SummaryWriter(str(run_dir))
    for step, values in rows:
        for tag, value in values.items():
            writer.add_scalar(tag, value, step)
    writer.close()


REACHED = "Metrics/lift_height/reached"
ERROR = "Metrics/lift_height/position_error"


def lab_events(run_dir) -> None:
    events(run_dir, [(k * ITERATION, {metrics.STEPS_PER_S: rate, metrics.SUCCESS_RATE: success,
                                      REACHED: latched, ERROR: 0.3 - 0.05 * k})
                     for k, rate, success, latched in [
                         (1, 10.0, 0.0, 0.0), (2, 300.0, 0.0, 0.2), (3, 300.0, 0.4, 0.6),
                         (4, 330.0, 0.6, 0.8), (5, 330.0, 0.8, 0.9)]])


def test_each_measure_is_compared_with_its_like_at_the_steps_both_reached(tmp_path):
    bench_lift = benchscripts.load("bench_lift")
    lab, mjlab = tmp_path / "lab", tmp_path / "mjlab"
    lab_events(lab)
    events(mjlab, [(k, {"Perf/total_fps": rate, "Metrics/lift_height/at_goal": at_goal,
                        "Metrics/lift_height/episode_success": latched, ERROR: 0.2})
                   for k, rate, at_goal, latched in [(1, 5.0, 0.0, 0.1), (2, 100.0, 0.5, 0.5),
                                                     (3, 110.0, 0.6, 0.75), (4, 110.0, 0.7, 0.8)]])
    row = bench_lift.compare(lab, mjlab, mjlab_envs=ENVS)
    assert row["common_steps"] == 4 * ITERATION  # mjlab's last iteration
    assert row["lab_steps_per_s"] == pytest.approx(330.0)  # the median after the first two
    assert row["mjlab_steps_per_s"] == pytest.approx(110.0)
    assert row["ratio"] == pytest.approx(3.0)
    assert (row["lab_success"], row["mjlab_success"]) == pytest.approx((0.6, 0.7))
    assert (row["lab_reached"], row["mjlab_reached"]) == pytest.approx((0.8, 0.8))
    assert (row["lab_error"], row["mjlab_error"]) == pytest.approx((0.1, 0.2))
    assert row["lab_success_first"] == {0.1: 3 * ITERATION, 0.5: 4 * ITERATION,
                                        0.7: 5 * ITERATION}
    assert row["mjlab_success_first"] == {0.1: 2 * ITERATION, 0.5: 2 * ITERATION,
                                          0.7: 4 * ITERATION}
    assert row["lab_reached_first"] == {0.1: 2 * ITERATION, 0.5: 3 * ITERATION,
                                        0.7: 4 * ITERATION}
    assert row["mjlab_reached_first"][0.1] == ITERATION


def test_a_lab_run_alone_is_read_at_the_steps_asked(tmp_path, capsys):
    bench_lift = benchscripts.load("bench_lift")
    lab_events(tmp_path / "lab")
    row = bench_lift.compare(tmp_path / "lab", None, mjlab_envs=ENVS, at=3 * ITERATION + 5)
    assert row["common_steps"] == 3 * ITERATION + 5 and "ratio" not in row
    assert (row["lab_success"], row["lab_reached"]) == pytest.approx((0.4, 0.6))
    assert row["lab_error"] == pytest.approx(0.15)
    assert row["lab_success_first"] == {0.1: 3 * ITERATION, 0.5: 4 * ITERATION,
                                        0.7: 5 * ITERATION}
    assert not any(key.startswith("mjlab_") and row[key] is not None for key in row)
    assert "mjlab" not in capsys.readouterr().out
