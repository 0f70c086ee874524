"""The `lab` command surface: train → play → export as a user runs them, and bad input."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path
from unittest import mock

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from oneline import assert_one_line_error
from typer.testing import CliRunner

from labcli import __version__
from labcli.commands.app import app
from labcli.runs import export

SMALL = ["--num-envs", "4", "--max-iterations", "2", "--set", "agent.n_steps=8",
         "--set", "agent.batch_size=16", "--set", "agent.n_epochs=1",
         "--set", "agent.normalize_obs=true"]
TRAIN = ["train", "--task", "cartpole", "--framework", "sb3", *SMALL, "--run-name", "cli"]


def lab(*args: str, logs: Path) -> object:
    return CliRunner().invoke(app, [*args], env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "200"})


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    """A logs dir with one small finished sb3 run of cartpole."""
    logs = tmp_path_factory.mktemp("logs")
    # CliRunner leaves sys.argv as the test process's: the command line the run records.
    with mock.patch.object(sys, "argv", ["/usr/bin/lab", *TRAIN]):
        result = lab(*TRAIN, logs=logs)
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
    assert (found / "command.txt").read_text() == shlex.join(["lab", *TRAIN]) + "\n"
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
    session = ort.InferenceSession(str(exported / "policy.onnx"))
    actions = session.run(None, {"obs": np.zeros((7, 4), np.float32)})[0]
    assert actions.shape == (7, 1) and np.all(np.abs(actions) <= 1)


def test_the_export_check_allows_float32_rounding_of_large_actions(tmp_path):
    """A normalizer's near-constant input (a pose command's fixed quaternion) turns wide random
    check observations into actions at the clip: float32 rounds those by more than 1e-5, in
    torch as in ONNX Runtime, so the check allows 1e-5 of the largest action."""
    class Policy(torch.nn.Module):  # exports name their input `obs`
        def __init__(self):
            super().__init__()
            self.mlp = torch.nn.Sequential(torch.nn.Linear(36, 256), torch.nn.ELU(),
                                           torch.nn.Linear(256, 8))

        def forward(self, obs: torch.Tensor) -> torch.Tensor:
            return self.mlp(obs)

    torch.manual_seed(0)
    policy = Policy().eval()
    obs = torch.randn(256, 36) * 100.0
    with torch.inference_mode():
        expected = policy(obs).numpy()
        exact = policy.double()(obs.double()).numpy()
    assert np.abs(expected).max() > 100.0
    assert np.abs(expected - exact).max() > 1e-5  # float32's own rounding
    tolerance = export.check_tolerance(expected)
    assert np.abs(expected - exact).max() < tolerance
    assert export.check_tolerance(expected / np.abs(expected).max()) == export.TOLERANCE
    path = tmp_path / "policy.onnx"
    export._export_onnx(policy.float(), obs, path, {"task": "t"})
    assert np.abs(export._run_onnx(path, obs) - expected).max() < tolerance


def test_each_export_is_described_beside_it_and_inside_it(logs):
    """policy.onnx.json and policy.pt.json each name their own file and say what a deployment
    needs: observations with units and conventions, the action-to-command rule, the timing,
    versions and provenance; the ONNX model and the TorchScript archive carry the same."""
    exported = run_dir(logs) / "exported"
    for fmt in ("onnx", "jit"):
        assert lab("export", fmt, logs=logs).exit_code == 0
    beside = {name: json.loads((exported / f"{name}.json").read_text())
              for name in ("policy.onnx", "policy.pt")}
    assert beside["policy.onnx"]["file"] == "policy.onnx" and beside["policy.onnx"]["format"] \
        == "onnx"
    assert beside["policy.pt"]["file"] == "policy.pt" and beside["policy.pt"]["format"] == "jit"
    meta = beside["policy.onnx"]
    assert (meta["task"], meta["framework"], meta["checkpoint"]) == ("cartpole", "sb3",
                                                                     "model_2.zip")
    assert meta["run"] == run_dir(logs).name and meta["iteration"] == 2
    assert meta["versions"]["lab"] and meta["versions"]["stable-baselines3"] \
        and meta["versions"]["mujoco"] and meta["versions"]["onnx"]
    observations = {o["name"]: o["unit"] for o in meta["input"]["observations"]}
    assert list(observations) == ["cart_pos", "pole_angle", "cart_vel", "pole_vel"]
    assert observations["pole_angle"].startswith("rad from upright, wrapped to [-pi, pi)")
    assert meta["input"]["normalizer_included"] and meta["input"]["shape"] == ["batch", 4]
    assert meta["output"]["actions"] == [{"action": "cart_force", "actuator": "cart_force",
                                          "command": "ctrl = 40 * action", "unit": "N along +x"}]
    assert meta["output"]["range"] == [-1.0, 1.0]
    assert meta["timing"] == {"control_dt": 0.02, "physics_dt": 0.01, "decimation": 2}
    assert meta["check"]["max_abs_diff"] < 1e-5
    model = onnx.load(str(exported / "policy.onnx"))
    inside = json.loads({p.key: p.value for p in model.metadata_props}["lab"])
    assert inside == {k: v for k, v in meta.items() if k != "check"}
    extra = {"lab.json": ""}
    torch.jit.load(str(exported / "policy.pt"), _extra_files=extra)
    assert json.loads(extra["lab.json"])["file"] == "policy.pt"


# Bad input: one line on stderr, exit code 2, no traceback, nothing written ---------------------
BAD = {
    "unknown task": (["train", "--task", "cartpol", "--framework", "sb3"],
                     ["unknown task 'cartpol'", "did you mean 'cartpole'", "cartpole"]),
    "unknown framework": (["train", "--task", "cartpole", "--framework", "sb4"],
                          ["unknown framework 'sb4'", "rsl_rl, sb3, sb3_sac, sb3_td3, skrl"]),
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


def test_bench_threads_measures_each_thread_count_beside_the_rollout(tmp_path):
    result = lab("bench", "--task", "cartpole", "--num-envs", "4,6", "--seconds", "0.1",
                 "--threads", "1,2", "--json", logs=tmp_path)
    assert result.exit_code == 0, result.output
    rows = json.loads(result.stdout)
    assert [(row["threads"], row["num_envs"]) for row in rows] == [(1, 4), (1, 6), (2, 4), (2, 6)]
    assert all(row["rollout_steps_per_s"] > 0 and row["ratio_to_rollout"] > 0 for row in rows)
    bad = lab("bench", "--task", "cartpole", "--threads", "0", logs=tmp_path)
    assert bad.exit_code == 2 and bad.stderr.startswith("error: --threads must be positive")
    assert_one_line_error(lab("bench", "--task", "cartpole", "--threads", "2,x", logs=tmp_path))


@pytest.mark.parametrize("counts", ["0", "4,x", ""])
def test_bench_rejects_bad_env_counts(tmp_path, counts):
    result = lab("bench", "--task", "cartpole", "--num-envs", counts, logs=tmp_path)
    assert result.exit_code == 2 and result.stderr.startswith("error: --num-envs")


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_files_a_user_reads_follow_the_user_s_umask(umask, tmp_path):
    """Results are created as `open()` would create them, so that colleagues on a shared
    machine can read them where the umask lets them, not 0600."""
    logs = tmp_path / "logs"
    script = (f"umask {umask:03o} && {sys.executable} -m labcli train --task cartpole "
              f"--framework rsl_rl --num-envs 4 --max-iterations 1 "
              f"--set agent.num_steps_per_env=8 --set agent.actor_hidden_dims=[8] "
              f"--set agent.critic_hidden_dims=[8] && {sys.executable} -m labcli export onnx")
    result = subprocess.run(["sh", "-c", script], capture_output=True, text=True,
                            env={**os.environ, "LAB_LOGS_DIR": str(logs)}, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    (run,) = (logs / "rsl_rl" / "cartpole").iterdir()
    wanted = {"file": 0o666 & ~umask, "dir": 0o777 & ~umask}
    for path in [run, *run.rglob("*")]:
        kind = "dir" if path.is_dir() else "file"
        assert path.stat().st_mode & 0o777 == wanted[kind], (path.relative_to(logs),
                                                              oct(path.stat().st_mode))
