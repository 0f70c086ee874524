"""`lab runs` (the runs table and honest run states) and `lab plot` (curves from TensorBoard)."""

from __future__ import annotations

import io
import json
import os
import socket
import subprocess
import sys
from datetime import datetime
from pathlib import Path

import matplotlib.image
import pytest
from rich.console import Console

from labcli.envs import metrics
from labcli.errors import LabError
from labcli.runs import plot, rundir, training
from labcli.testing import SHORT_EPISODE, train_small

SMALL = ["agent.n_steps=8", "agent.batch_size=16", "agent.n_epochs=1", SHORT_EPISODE]


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    """Two finished cartpole runs (sb3 and skrl) and one of a gymnasium task."""
    logs = tmp_path_factory.mktemp("logs")
    train_small("sb3", logs, 3, SMALL)
    train_small("skrl", logs, 3, ["agent.rollouts=8", SHORT_EPISODE])
    training.train("gym:InvertedPendulum-v5", "sb3", num_envs=2, max_iterations=2,
                   overrides=SMALL[:3], logs_dir=logs, console=Console(file=io.StringIO()),
                   command=["lab", "test"])
    return logs


def fake_run(logs: Path, name: str, **manifest) -> Path:
    """A run dir as `lab train` leaves it while training: a manifest, no summary yet."""
    run = logs / "rsl_rl" / "cartpole" / name
    run.mkdir(parents=True)
    base = {"task": "cartpole", "framework": "rsl_rl", "state": "running",
            "started": datetime.now().isoformat(timespec="seconds"),
            "host": socket.gethostname(), "pid": os.getpid()}
    rundir.write_json(run, rundir.MANIFEST, {**base, **manifest})
    return run


def test_finished_runs_show_their_summary(logs):
    rows = rundir.table(logs)
    assert [(r.framework, r.task) for r in rows] == [
        ("sb3", "gym:InvertedPendulum-v5"), ("skrl", "cartpole"), ("sb3", "cartpole")]
    for row in rows:
        summary = json.loads((row.dir / rundir.SUMMARY).read_text())
        assert row.state == "finished" and row.steps == summary["steps"] > 0
        assert row.mean_return == summary["mean_return"] and row.wall_time_s > 0
    assert [r.framework for r in rundir.table(logs, task="cartpole")] == ["skrl", "sb3"]
    assert [r.task for r in rundir.table(logs, framework="skrl")] == ["cartpole"]


def test_run_name_is_what_follows_the_time_stamp():
    assert rundir.run_name(Path("2026-11-23_13-38-38_peer_2")) == "peer_2"
    assert rundir.run_name(Path("2026-11-23_13-38-38")) == ""
    assert rundir.run_name(Path("2026-11-23_13-38-38-1")) == "-1"  # second run of that second


def test_the_table_states_come_from_run_state(tmp_path):
    """Each row's state is `rundir.run_state`'s (its cases are tested in test_runs.py): a live
    process of this host runs, a dead one failed, an ended run says how it ended."""
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    fake_run(tmp_path, "alive", **rundir.process_identity())
    fake_run(tmp_path, "dead_pid", pid=int(dead.stdout))
    interrupted = fake_run(tmp_path, "interrupted")
    rundir.write_json(interrupted, rundir.SUMMARY, {"state": "interrupted", "steps": 64})
    states = {row.dir.name: row.state for row in rundir.table(tmp_path)}
    assert states == {"alive": "running", "dead_pid": "failed", "interrupted": "interrupted"}
    (running,) = rundir.table(tmp_path, state="running")
    assert running.steps is None and running.wall_time_s is not None


def test_plot_draws_one_curve_per_run(logs, tmp_path):
    selected = plot.select(logs_dir=logs, last=2, task="cartpole")
    result = plot.plot(selected, output=tmp_path / "curves.png")
    assert [r.dir for r in result.plotted] == [r.dir for r in selected] and not result.skipped
    image = matplotlib.image.imread(result.path)
    assert image.shape[:2] == (500, 800)
    assert (image[..., :3].std(axis=(0, 1)) > 0.05).all()  # drawn, not a blank canvas


def test_plot_any_logged_tag_and_name_the_tags_of_an_unknown_one(logs, tmp_path):
    selected = plot.select(logs_dir=logs)
    plot.plot(selected, tmp_path / "length.png", metrics.MEAN_LENGTH)
    with pytest.raises(LabError) as info:
        plot.plot(selected, tmp_path / "nope.png", "Train/nope")
    assert "Train/nope" in info.value.message and metrics.MEAN_RETURN in info.value.hint
    assert not (tmp_path / "nope.png").exists()


@pytest.mark.parametrize("kind", ["directory", "fifo"])
def test_plot_refuses_events_that_are_not_regular_files(logs, tmp_path, kind):
    """TensorBoard's reader failed inside on a directory and would block on a FIFO."""
    source = plot.select(logs_dir=logs, task="cartpole")[0].dir
    run = tmp_path / "run"
    (run / "params").mkdir(parents=True)
    for name in (rundir.MANIFEST, rundir.SUMMARY, "params/env.yaml", "params/agent.yaml"):
        if (source / name).exists():
            (run / name).write_bytes((source / name).read_bytes())
    odd = run / "events.out.tfevents.1.odd"
    odd.mkdir() if kind == "directory" else os.mkfifo(odd)
    with pytest.raises(LabError, match="events.out.tfevents.1.odd is not a regular file"):
        plot.plot(plot.select([run]), output=tmp_path / "curves.png")
    assert not (tmp_path / "curves.png").exists()


def test_plot_needs_runs_and_a_png_name(tmp_path):
    with pytest.raises(LabError, match="no runs found"):
        plot.select(logs_dir=tmp_path)
    with pytest.raises(LabError, match="PNG"):
        plot.plot([], output=tmp_path / "curves.pdf")
