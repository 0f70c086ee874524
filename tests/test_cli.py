"""The `lab` command surface: train → play → export as a user runs them, and bad input."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
from oneline import assert_one_line_error
from typer.testing import CliRunner

from labcli import __version__
from labcli.commands.app import app

SMALL = ["--num-envs", "4", "--max-iterations", "2", "--set", "agent.n_steps=8",
         "--set", "agent.batch_size=16", "--set", "agent.n_epochs=1",
         "--set", "agent.normalize_obs=true"]


def lab(*args: str, logs: Path) -> object:
    return CliRunner().invoke(app, [*args], env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "200"})


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    """A logs dir with one small finished sb3 run of cartpole."""
    logs = tmp_path_factory.mktemp("logs")
    result = lab("train", "--task", "cartpole", "--framework", "sb3", *SMALL, "--run-name", "cli",
                 logs=logs)
    assert result.exit_code == 0, result.output
    return logs


def run_dir(logs: Path) -> Path:
    (found,) = (logs / "sb3" / "cartpole").glob("*_cli")
    return found


def test_version_and_help():
    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0 and __version__ in result.stdout
    for command in ("list", "train", "play", "export"):
        result = CliRunner().invoke(app, [command, "--help"])
        assert result.exit_code == 0 and "Example: lab" in result.stdout


def test_train_writes_the_run_dir_and_prints_a_summary(logs):
    found = run_dir(logs)
    assert (found / "params" / "env.yaml").is_file() and (found / "params" / "agent.yaml").is_file()
    # Under CliRunner sys.argv is pytest's; the real command line is checked by the bench script.
    assert (found / "command.txt").read_text().startswith("lab ")
    summary = json.loads((found / "summary.json").read_text())
    assert summary["state"] == "finished" and summary["iterations"] == 2
    manifest = json.loads((found / "run.json").read_text())
    assert manifest["task"] == "cartpole" and manifest["num_envs"] == 4


def test_a_run_name_with_brackets_is_printed_as_it_is(tmp_path):
    result = lab("train", "--task", "cartpole", "--framework", "sb3", *SMALL, "--run-name",
                 "a[bold]b", logs=tmp_path)
    assert result.exit_code == 0, result.output
    assert "_a[bold]b: finished" in result.stdout


def test_play_last_prints_episodes_and_success_rate(logs):
    result = lab("play", "--last", "--episodes", "3", logs=logs)
    assert result.exit_code == 0, result.output
    assert "3 episodes: mean return" in result.stdout and "success rate" in result.stdout


def test_export_onnx_runs_in_onnxruntime(logs):
    result = lab("export", "onnx", "--run", str(run_dir(logs)), logs=logs)
    assert result.exit_code == 0, result.output
    assert "max abs difference from torch" in result.stdout
    exported = run_dir(logs) / "exported"
    meta = json.loads((exported / "policy.json").read_text())
    assert meta["input"]["size"] == 4 and meta["output"]["names"] == ["cart_force"]
    assert meta["normalizer_included"] and meta["check"]["max_abs_diff"] < 1e-5
    session = ort.InferenceSession(str(exported / "policy.onnx"))
    actions = session.run(None, {"obs": np.zeros((7, 4), np.float32)})[0]
    assert actions.shape == (7, 1) and np.all(np.abs(actions) <= 1)


def test_export_jit(logs):
    result = lab("export", "jit", logs=logs)
    assert result.exit_code == 0, result.output
    assert (run_dir(logs) / "exported" / "policy.pt").is_file()


# Bad input: one line on stderr, exit code 2, no traceback, nothing written ---------------------
BAD = {
    "unknown task": (["train", "--task", "cartpol", "--framework", "sb3"],
                     ["unknown task 'cartpol'", "did you mean 'cartpole'", "cartpole"]),
    "unknown framework": (["train", "--task", "cartpole", "--framework", "sb4"],
                          ["unknown framework 'sb4'", "rsl_rl, sb3, skrl"]),
    "unknown --set key": (["train", "--task", "cartpole", "--framework", "sb3", "--set",
                           "agent.learning_rat=1"], ["agent.learning_rat", "agent.learning_rate"]),
    "ill-typed --set": (["train", "--task", "cartpole", "--framework", "sb3", "--set",
                         "agent.n_steps=many"], ["agent.n_steps", "expected int"]),
    "malformed --set": (["train", "--task", "cartpole", "--framework", "sb3", "--set", "lr"],
                        ["SECTION.KEY=VALUE"]),
    "non-positive --num-envs": (["train", "--task", "cartpole", "--framework", "sb3",
                                 "--num-envs", "0"], ["--num-envs", "positive"]),
    "missing checkpoint": (["train", "--task", "cartpole", "--framework", "sb3", "--checkpoint",
                            "nowhere/model_5.zip"], ["does not exist"]),
    "no runs to resume": (["train", "--task", "cartpole", "--framework", "sb3", "--checkpoint",
                           "latest"], ["no complete checkpoint"]),
    "play with no runs": (["play", "--last"], ["no runs found"]),
    "export with no runs": (["export", "onnx"], ["no runs found"]),
    "play a missing run": (["play", "--run", "nowhere"], ["does not exist"]),
    "play zero envs": (["play", "--num-envs", "0"], ["--num-envs", "positive"]),
    # Square brackets in a message are text, not rich markup to be dropped.
    "brackets in the message": (["train", "--task", "cartpole", "--framework", "sb3", "--set",
                                 "agent.activation=elu[warp]"], ["elu[warp]"]),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, case):
    args, phrases = BAD[case]
    logs = tmp_path / "logs"
    result = lab(*args, logs=logs)
    assert_one_line_error(result, *phrases)
    assert not logs.exists() or not any(logs.rglob("*.*"))


def test_corrupt_checkpoint_is_one_line_exit_2(tmp_path, logs):
    broken = tmp_path / "logs"
    source = run_dir(logs)
    target = broken / "sb3" / "cartpole" / source.name
    shutil.copytree(source / "params", target / "params")
    shutil.copy(source / "run.json", target)
    (target / "model_2.zip").write_bytes(b"garbage")
    result = lab("play", "--last", logs=broken)
    assert_one_line_error(result, "model_2.zip")


def test_the_installed_console_script_runs():
    result = subprocess.run([sys.executable, "-m", "labcli", "--version"], capture_output=True,
                            text=True, check=True)
    assert result.stdout.strip() == f"lab {__version__}"


def test_bench_prints_env_and_training_rates_as_json(tmp_path):
    result = lab("bench", "--task", "cartpole", "--num-envs", "4,8", "--seconds", "0.2",
                 "--framework", "skrl", "--json", logs=tmp_path / "logs")
    assert result.exit_code == 0, result.output
    rows = json.loads(result.stdout)
    assert [row["num_envs"] for row in rows] == [4, 8]
    for row in rows:
        assert row["backend"] == "cpu" and row["env_steps_per_s"] > 0
        assert row["framework"] == "skrl" and row["train_steps_per_s"] > 0
    assert not (tmp_path / "logs").exists()  # the training runs are thrown away


def test_bench_threads_sets_the_cpu_backends_physics_threads(tmp_path):
    result = lab("bench", "--task", "cartpole", "--num-envs", "4", "--seconds", "0.1",
                 "--threads", "1", "--json", logs=tmp_path)
    assert result.exit_code == 0, result.output
    (row,) = json.loads(result.stdout)
    assert row["threads"] == 1 and row["env_steps_per_s"] > 0
    bad = lab("bench", "--task", "cartpole", "--threads", "0", logs=tmp_path)
    assert bad.exit_code == 2 and bad.stderr.startswith("error: --threads must be a positive")


@pytest.mark.parametrize("counts", ["0", "4,x", ""])
def test_bench_rejects_bad_env_counts(tmp_path, counts):
    result = lab("bench", "--task", "cartpole", "--num-envs", counts, logs=tmp_path)
    assert result.exit_code == 2 and result.stderr.startswith("error: --num-envs")
