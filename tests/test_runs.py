"""Run dirs: distinct names under a frozen clock, and the state a runs table shows."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from datetime import datetime

import yaml
from rich.console import Console

from labcli import testing
from labcli.envs import metrics
from labcli.runs import rundir, training
from labcli.runs.plot import read_scalars


class FrozenClock(datetime):
    @classmethod
    def now(cls, tz=None):
        return cls(2026, 1, 2, 3, 4, 5)


def test_runs_started_in_the_same_second_get_distinct_dirs(tmp_path, monkeypatch):
    monkeypatch.setattr(rundir, "datetime", FrozenClock)
    made = [rundir.create(tmp_path, "sb3", "cartpole", "same").dir for _ in range(3)]
    assert [d.name for d in made] == ["2026-01-02_03-04-05_same", "2026-01-02_03-04-05_same-1",
                                      "2026-01-02_03-04-05_same-2"]
    assert all(d.is_dir() for d in made)


def write_run(tmp_path, manifest: dict, summary: dict | None = None) -> rundir.Run:
    run = rundir.Run(tmp_path)
    rundir.write_json(tmp_path, rundir.MANIFEST, manifest)
    if summary is not None:
        rundir.write_json(tmp_path, rundir.SUMMARY, summary)
    return run


def test_run_state_follows_the_summary_and_the_process(tmp_path):
    me = rundir.process_identity()
    assert me["pid"] == os.getpid() and me["pid_started"] is not None
    running = {"state": rundir.RUNNING, **me}
    assert rundir.run_state(write_run(tmp_path, running, {"state": rundir.RUNNING})) == \
        rundir.RUNNING
    for state in (rundir.FINISHED, rundir.INTERRUPTED, rundir.FAILED):
        assert rundir.run_state(write_run(tmp_path, running, {"state": state})) == state
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead = {**running, "pid": int(gone.stdout)}  # a process that ended without a summary
    assert rundir.run_state(write_run(tmp_path, dead, {"state": rundir.RUNNING})) == rundir.FAILED
    reused = {**running, "pid_started": me["pid_started"] - 1}  # same pid, another process
    assert rundir.run_state(write_run(tmp_path, reused, {"state": rundir.RUNNING})) == rundir.FAILED
    elsewhere = {**dead, "host": "another-machine"}  # cannot be checked: trusted
    assert rundir.run_state(write_run(tmp_path, elsewhere, {"state": rundir.RUNNING})) == \
        rundir.RUNNING
    (tmp_path / rundir.SUMMARY).unlink()  # summary not written yet: the manifest says
    assert rundir.run_state(write_run(tmp_path, running)) == rundir.RUNNING
    assert json.loads((tmp_path / rundir.MANIFEST).read_text())["pid"] == os.getpid()


def test_a_run_is_reproduced_from_its_params_dir(tmp_path):
    """params/env.yaml and params/agent.yaml hold everything, the seed included: fed back as a
    --config file (no other flags) they give the same returns and the same policy."""
    sets = ["agent.n_steps=8", "agent.batch_size=16", "agent.n_epochs=2", "agent.net_arch=[16]",
            testing.SHORT_EPISODE]
    first = testing.train_small("sb3", tmp_path / "a", 2, sets, seed=7)
    params = first.run.dir / "params"
    agent = yaml.safe_load((params / "agent.yaml").read_text())
    assert agent["seed"] == 7
    config = tmp_path / "again.yaml"
    config.write_text(yaml.safe_dump({"env": yaml.safe_load((params / "env.yaml").read_text()),
                                      "agent": agent}))
    again = training.train("cartpole", "sb3", config_file=config, logs_dir=tmp_path / "b",
                           console=Console(file=io.StringIO()))
    returns = [[v for _, v in sorted(read_scalars(o.run.dir)[metrics.MEAN_RETURN])]
               for o in (first, again)]
    assert returns[0] == returns[1] and len(returns[0]) == 2
    assert (again.run.dir / "params" / "agent.yaml").read_text() == \
        (params / "agent.yaml").read_text()


def test_a_progress_line_shows_the_rate_since_the_last_line(monkeypatch):
    """Not the printed iteration's own rate: that may be an iteration that wrote a
    checkpoint, the slowest kind."""
    from labcli.runs import progress

    out = io.StringIO()
    clock = iter([1.0, 4.0])
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
    with progress.TrainProgress(20, "train", Console(file=out, width=200)) as bar:
        bar.update(1, 100.0, None, None, steps=100)  # a line: its own rate
        bar.update(2, 100.0, None, None, steps=200)  # no line
        bar.update(3, 50.0, 1.5, 0.25, steps=300)  # a line: 200 steps in 3 s
    lines = out.getvalue().splitlines()
    assert lines[1:] == ["  iteration 1/20  100 steps/s",
                         "  iteration 3/20  67 steps/s  return 1.5  success 25%"]
