"""`--logger wandb`: a run's figures, settings and exports in Weights & Biases, offline
(WANDB_MODE=offline: W&B writes into the run dir what `wandb sync` would upload)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import wandb_records
from typer.testing import CliRunner

from labcli.commands.app import app

TRAIN = ["train", "--task", "cartpole", "--framework", "rsl_rl", "--num-envs", "16",
         "--set", "agent.num_steps_per_env=8"]


def lab(*args: str, logs: Path, **env: str):
    return CliRunner().invoke(app, list(args), env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "300",
                                                    "WANDB_MODE": "offline", **env})


def offline_runs(run_dir: Path, run_id: str) -> list[Path]:
    """The W&B run's files of each session (training, resume, export), oldest first. A session
    begun in the same second as the one before gets W&B's folder name with "-1" added."""
    return [wandb_records.finished(d)
            for d in sorted(run_dir.glob(f"wandb/offline-run-*-{run_id}*"))]


def test_a_run_s_figures_settings_resume_and_export_go_to_one_wandb_run(tmp_path):
    trained = lab(*TRAIN, "--max-iterations", "3", "--logger", "wandb", logs=tmp_path)
    assert trained.exit_code == 0, trained.output
    (run_dir,) = tmp_path.glob("rsl_rl/cartpole/*")
    run_id = json.loads((run_dir / "wandb.json").read_text())["id"]
    (first,) = offline_runs(run_dir, run_id)
    (run,) = wandb_records.of_type(first, "run")
    assert (run.run_id, run.project, run.display_name, run.run_group) == (
        run_id, "lab", run_dir.name, "cartpole/rsl_rl")
    config = {item.key: json.loads(item.value_json) for item in run.config.update}
    assert config["task"] == "cartpole" and config["agent"]["max_iterations"] == 3
    assert config["env"]["num_envs"] == 16
    # A row per iteration: lab's figures and the library's, against env steps.
    rows = [wandb_records.row(h) for h in wandb_records.of_type(first, "history")]
    assert [json.loads(r["env_steps"]) for r in rows] == [128, 256, 384]
    for tag in ("Perf/steps_per_s", "Loss/value", "sim/mujoco_warnings"):
        assert all(tag in r for r in rows), tag

    resumed = lab(*TRAIN, "--checkpoint", "latest", "--max-iterations", "5", "--logger",
                  "wandb", logs=tmp_path)
    assert resumed.exit_code == 0, resumed.output
    assert json.loads((run_dir / "wandb.json").read_text())["id"] == run_id
    later = offline_runs(run_dir, run_id)[-1]
    rows = [wandb_records.row(h) for h in wandb_records.of_type(later, "history")]
    assert [json.loads(r["env_steps"]) for r in rows] == [512, 640]

    exported = lab("export", "onnx", "--last", logs=tmp_path)
    assert exported.exit_code == 0, exported.output
    assert "not logged" not in exported.output
    (artifact,) = wandb_records.of_type(offline_runs(run_dir, run_id)[-1], "artifact")
    assert artifact.type == "model"
    assert {f.path for f in artifact.manifest.contents} == {"policy.onnx", "policy.onnx.json"}


def test_without_wandb_installed_it_is_one_line_before_anything_is_written(tmp_path,
                                                                            monkeypatch):
    monkeypatch.setitem(sys.modules, "wandb", None)  # `import wandb` raises ImportError
    result = lab(*TRAIN, "--max-iterations", "1", "--logger", "wandb", logs=tmp_path)
    assert result.exit_code == 2
    assert "needs Weights & Biases" in result.output and "lab[wandb]" in result.output
    assert not list(tmp_path.iterdir())


def test_an_unknown_logger_is_one_line(tmp_path):
    result = lab(*TRAIN, "--logger", "mlflow", logs=tmp_path)
    assert result.exit_code == 2 and "tensorboard" in result.output


def test_wandb_that_cannot_start_is_one_line(tmp_path):
    """Online, with no API key: in a process of its own, as W&B's settings are per process."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("WANDB_")}
    result = subprocess.run(
        [sys.executable, "-m", "labcli", *TRAIN, "--max-iterations", "1", "--logger", "wandb"],
        capture_output=True, text=True, env={**env, "LAB_LOGS_DIR": str(tmp_path / "logs"),
                                              "HOME": str(tmp_path), "WANDB_MODE": "online"})
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()[-1:]
    assert line.startswith("error: Weights & Biases could not start a run: ") and \
        "WANDB_MODE=offline" in line, result.stderr
