"""Data-parallel training on two GPUs as a user runs it (`lab train --nproc 2`, NCCL): each
framework learns cartpole to success, and a Ctrl-C checkpoints both ranks and the run resumes.
What gloo on the CPU cannot show: NCCL's collectives inside the graphed updates, one GPU per
rank. Skipped where fewer than two GPUs are visible."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import torch

from labcli.runs import rundir

pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(torch.cuda.device_count() < 2, reason="needs two CUDA GPUs"),
]


def _train(logs, framework: str, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "labcli", "train", "--task", "cartpole", "--framework", framework,
         "--backend", "warp", "--nproc", "2", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "LAB_LOGS_DIR": str(logs)})


def _summary(logs, framework: str) -> dict:
    (run_dir,) = (logs / framework / "cartpole").iterdir()
    return json.loads((run_dir / rundir.SUMMARY).read_text())


@pytest.mark.parametrize("framework", ["rsl_rl", "skrl"])
def test_two_gpus_learn_cartpole(tmp_path, framework):
    proc = _train(tmp_path, framework)
    _, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err
    summary = _summary(tmp_path, framework)
    assert summary["state"] == rundir.FINISHED
    assert summary["success_rate"] >= 0.9, summary


def test_ctrl_c_on_two_gpus_checkpoints_and_the_run_resumes(tmp_path):
    proc = _train(tmp_path, "rsl_rl", "--max-iterations", "100000")
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and not list(tmp_path.glob("rsl_rl/cartpole/*/model_*.pt")):
        time.sleep(1)
    time.sleep(5)
    proc.send_signal(signal.SIGINT)  # as Ctrl-C reaches the launcher
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "torch" not in err and "Warning" not in err, err
    summary = _summary(tmp_path, "rsl_rl")
    assert summary["state"] == rundir.INTERRUPTED
    stopped = summary["iterations"]
    assert summary["checkpoint"] == f"model_{stopped}.pt"

    resumed = _train(tmp_path, "rsl_rl", "--checkpoint", "latest", "--max-iterations",
                     str(stopped + 10))
    _, err = resumed.communicate(timeout=600)
    assert resumed.returncode == 0, err
    assert "note:" not in err  # every rank went on with its own episodes
    summary = _summary(tmp_path, "rsl_rl")
    assert summary["state"] == rundir.FINISHED and summary["iterations"] == stopped + 10
