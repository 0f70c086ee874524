"""bench/bench_success.py's report: seed by seed, then each task's median against its goal,
with runs that failed to start or finish among them."""

from __future__ import annotations

import benchscripts
import pytest


@pytest.fixture(scope="module")
def bench_success():
    return benchscripts.load("bench_success")


def finished(seed: int, success_s: float | None) -> dict:
    return {"task": "ant", "seed": seed, "steps_per_s": 12345.0, "training_s": 200.0,
            "state": "finished", "final_success": 0.95, "success_s": success_s,
            "success_steps": None if success_s is None else 1_000_000}


def test_the_median_counts_a_run_that_never_got_there_as_infinite(bench_success, capsys):
    rows = [finished(0, 60.0), finished(1, None), finished(2, 90.0)]
    bench_success.report(rows, 0.9, {"ant": 180.0})
    out = capsys.readouterr().out
    assert "| ant | 1 | 12,345 | never | - | 200 (finished) | 0.95 |" in out
    assert "| ant | 90 s | 180.0 s | 2 of 3 | yes |" in out


def test_a_task_whose_every_run_failed_is_reported_not_raised(bench_success, capsys):
    rows = [{"task": "ant", "seed": 0, "exit": 2}, {"task": "ant", "seed": 1, "exit": 2},
            finished(0, 60.0) | {"task": "humanoid"}]
    bench_success.report(rows, 0.9, {"ant": 180.0})
    out = capsys.readouterr().out
    assert "| ant | 0 | exit 2 |" in out
    assert "| ant | no run finished | 180.0 s | 0 of 2 | no |" in out
    assert "| humanoid | 60 s | - | - | - |" in out


def test_a_run_never_played_to_success_names_its_best_checkpoint(bench_success):
    def played(rates):
        return finished(0, None) | {"played": {"reached": None, "rates": rates}}

    assert bench_success.never(played([[50, 0.2], [100, 0.77], [150, 0.5]])) == \
        "never (best 0.77, iteration 100)"
    assert bench_success.never(played([[50, 0.0], [100, 0.0]])) == \
        "never (0 at each of 2 checkpoints)"
    assert bench_success.never(finished(0, None)) == "never"
