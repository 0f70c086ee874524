"""`lab sim2sim` (labcli/runs/closed_loop.py) and the plain-MuJoCo loop (labcli/sim2sim.py) on a
real go1-flat export: lab's and the metadata's observations of the same state are equal, the
loop's first step moves the joints as lab's does, and an export whose metadata lists the joints
out of order fails the check."""

from __future__ import annotations

import io
import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import needs_menagerie
from rich.console import Console

from labcli.errors import LabError
from labcli.runs import closed_loop, export, training
from labcli.sim2sim import tracking_errors

pytestmark = needs_menagerie("unitree_go1")  # go1-flat's robot


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    logs = tmp_path_factory.mktemp("logs")
    outcome = training.train("go1-flat", "rsl_rl", num_envs=4, max_iterations=1,
                             logs_dir=logs, console=Console(file=io.StringIO()),
                             command=["lab", "test"],
                             # 2 s episodes: 100 steps on each side of a check
                             overrides=["agent.num_steps_per_env=8", "env.episode_length_s=2"])
    result = export.export("onnx", run_dir=outcome.run.dir)
    return outcome.run.dir, result.metadata


def _edit(metadata, change):
    meta = json.loads(metadata.read_text())
    change(meta["deployment"])
    metadata.write_text(json.dumps(meta))


def test_the_export_drives_plain_mujoco_as_lab_drives_its_env(exported):
    run_dir, metadata = exported
    meta = json.loads(metadata.read_text())
    assert (run_dir / "exported" / meta["mujoco_model"]).is_file()
    assert [t["kind"] for t in meta["deployment"]["observations"]] == [
        "base_lin_vel", "base_ang_vel", "projected_gravity", "generated_commands",
        "joint_pos_rel", "joint_vel_rel", "last_action"]
    result = closed_loop.check(run_dir=run_dir, episodes=2)
    assert result.obs_diff <= 1.0  # of the tolerance
    assert result.step_diff <= closed_loop.STEP_TOLERANCE
    assert result.passed
    # The same start states and commands: an untrained Go1 stands, far from its commands.
    assert result.plain.lin_vel_error == pytest.approx(result.lab.lin_vel_error, abs=0.05)


def test_joints_out_of_order_in_the_metadata_fail_the_check(exported, tmp_path):
    run_dir, metadata = exported
    saved = metadata.read_text()
    try:
        # The first two actions' joints named in the wrong order (their numbers in place): the
        # loop sends the hip's target to the thigh and the thigh's to the hip.
        def swap(d):
            first, second = d["joints"][:2]
            for key in ("joint", "actuator"):
                first[key], second[key] = second[key], first[key]

        _edit(metadata, swap)
        result = closed_loop.check(run_dir=run_dir, episodes=2)
        assert result.step_diff > closed_loop.STEP_TOLERANCE and not result.passed
        swapped = [j["joint"] for j in json.loads(saved)["deployment"]["joints"][:2]]
        assert result.step_worst in swapped
        # Joint positions read in the wrong order: the first observation already differs.
        metadata.write_text(saved)
        term = 4  # joint_pos
        _edit(metadata, lambda d: d["observations"][term]["names"].reverse())
        result = closed_loop.check(run_dir=run_dir, episodes=2)
        assert result.obs_diff > 1.0 and not result.passed
        assert result.obs_worst.startswith("joint_pos.")
    finally:
        metadata.write_text(saved)
    done = subprocess.run([sys.executable, "-m", "labcli", "sim2sim", "--run", str(run_dir),
                           "--episodes", "2"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_a_run_without_an_export_is_one_line(tmp_path):
    outcome = training.train("go1-flat", "rsl_rl", num_envs=2, max_iterations=1,
                             logs_dir=tmp_path, console=Console(file=io.StringIO()),
                             command=["lab", "test"], overrides=["agent.num_steps_per_env=4"])
    with pytest.raises(LabError, match="has no ONNX export") as info:
        closed_loop.check(run_dir=outcome.run.dir)
    assert "lab export onnx" in info.value.hint


def test_the_plain_loop_imports_no_torch():
    code = "import sys, labcli.sim2sim; print('torch' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True)
    assert done.stdout.strip() == "False"


def test_tracking_errors_by_hand():
    commands = np.array([[1.0, 0.0, 0.5]] * 2)
    lin = np.array([[0.5, 0.0], [1.0, 0.0]])
    yaw = np.array([0.0, 0.5])
    # Each step: |(1, 0) - v| = 0.5 then 0; |0.5 - w| = 0.5 then 0.
    assert tracking_errors(commands, lin, yaw, 0.02) == pytest.approx((0.25, 0.25))
    # Over a window of 0.04 s (weight 0.5), from rest (error = the command):
    # lin 1 -> 0.75 -> 0.375, yaw 0.5 -> 0.5 -> 0.25.
    assert tracking_errors(commands, lin, yaw, 0.02, 0.04) == pytest.approx((0.5625, 0.375))


def test_the_deployment_example_runs_the_export(exported):
    import re
    from pathlib import Path

    _, metadata = exported
    example = Path(__file__).parents[1] / "examples" / "deploy_mujoco.py"
    done = subprocess.run([sys.executable, str(example), str(metadata.with_suffix("")),
                           "--vx", "0.5", "--seconds", "2"], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) == 2 and all(re.match(
        r"t=\s+\d s  command \(0.50, 0.00, 0.00\)  kept vx=-?[\d.]+ .* base at z=[\d.]+ m$", line)
        for line in lines), done.stdout


def test_a_height_scan_is_cast_by_mujocos_rays_as_lab_reads_its_map(tmp_path):
    # go1-rough on a small grid of its stairs and rough ground (its other types left out).
    terrain = {"size": 4.0, "rows": 3, "cols": 2, "border": 1.0, "max_start_level": 2,
               "types": {"stairs": {"platform": 1.0, "step_height": [0.1, 0.2]},
                         "rough": {"platform": 1.0}, "stairs_down": None, "boxes": None,
                         "slope": None, "slope_down": None}}
    outcome = training.train(
        "go1-rough", "rsl_rl", num_envs=4, max_iterations=1, logs_dir=tmp_path,
        console=Console(file=io.StringIO()), command=["lab", "test"],
        overrides=["env.terrain=" + json.dumps(terrain), "env.episode_length_s=1.0",
                   "agent.num_steps_per_env=8"])
    metadata = export.export("onnx", run_dir=outcome.run.dir).metadata
    result = closed_loop.check(run_dir=outcome.run.dir, episodes=4)
    # Every input within its tolerance: the 187 heights' median within 1 cm of lab's map, the
    # rest within float32's rounding.
    assert result.obs_diff <= 1.0, result
    assert result.passed, result
    # A deployer who left out the scan's offset reads every height 0.5 m off.
    scan = next(i for i, t in enumerate(json.loads(metadata.read_text())["deployment"][
        "observations"]) if t["kind"] == "height_scan")
    _edit(metadata, lambda d: d["observations"][scan]["settings"].update(offset=0.0))
    result = closed_loop.check(run_dir=outcome.run.dir, episodes=4)
    assert result.obs_worst == "height_scan (median)" and result.obs_diff > 40, result
    assert not result.passed
