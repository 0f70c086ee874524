"""A shared run dir is data, never code (docs/robustness.md, "Trust"): files planted in a run dir
run no code when lab reads them, links planted in it are never followed by lab's writes, and
names and output paths that cannot work are one line with exit code 2.

Each planted file is made complete in the eyes of lab (its checkpoint's manifest is rewritten to
match, as an attacker would), so that lab does read it; each payload is shown to run under the
loader lab no longer uses."""

from __future__ import annotations

import base64
import builtins
import contextlib
import json
import os
import pickle
import shutil
import subprocess
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
from oneline import assert_one_line_error
from runfiles import remanifest
from typer.testing import CliRunner

from labcli.commands.app import app

SMALL = {
    "sb3": ["--set", "agent.n_steps=8", "--set", "agent.batch_size=16", "--set",
            "agent.n_epochs=1", "--set", "agent.normalize_obs=true"],
    "rsl_rl": ["--set", "agent.num_steps_per_env=8", "--set", "agent.num_learning_epochs=1"],
    "skrl": ["--set", "agent.rollouts=8", "--set", "agent.learning_epochs=1"],
}


def lab(*args: str, logs: Path):
    return CliRunner().invoke(app, list(args), env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "300"})


def train(logs: Path, framework: str, *extra: str):
    result = lab("train", "--task", "cartpole", "--framework", framework, "--num-envs", "4",
                 "--max-iterations", "2", "--set", "agent.save_interval=1", *SMALL[framework],
                 *extra, logs=logs)
    assert result.exit_code == 0, result.output
    (run_dir,) = logs.glob(f"{framework}/cartpole/*")
    return run_dir


class Payload:
    """Unpickled, it creates the file `marker`: the proof that code ran."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return builtins.open, (str(self.marker), "w")


def plant_sb3_payload(checkpoint: Path, marker: Path) -> None:
    """An SB3 zip whose `data` entry carries a pickled object, as SB3's own files do."""
    evil = checkpoint.with_suffix(".evil")
    with zipfile.ZipFile(checkpoint) as zin, zipfile.ZipFile(evil, "w") as zout:
        for info in zin.infolist():
            data = zin.read(info.filename)
            if info.filename == "data":
                fields = json.loads(data)
                fields["policy_kwargs"][":serialized:"] = base64.b64encode(
                    pickle.dumps(Payload(marker))).decode()
                data = json.dumps(fields).encode()
            zout.writestr(info, data)
    evil.replace(checkpoint)
    remanifest(checkpoint.parent, int(checkpoint.stem.rsplit("_", 1)[1]))


# Code execution --------------------------------------------------------------------------------
def test_an_sb3_checkpoint_with_a_pickled_payload_runs_no_code(tmp_path):
    from stable_baselines3 import PPO

    logs = tmp_path / "logs"
    run_dir = train(logs, "sb3")
    checkpoint = run_dir / "model_2.zip"
    marker = tmp_path / "marker"
    plant_sb3_payload(checkpoint, marker)
    with contextlib.suppress(Exception):
        PPO.load(checkpoint)  # SB3's own loader: the payload is live
    assert marker.exists()
    marker.unlink()
    for args in (["play", "--checkpoint", str(checkpoint), "--episodes", "2"],
                 ["play", "--run", str(run_dir), "--episodes", "2"],
                 ["play", "--last", "--episodes", "2"],
                 ["export", "onnx", "--run", str(run_dir)],
                 ["train", "--task", "cartpole", "--framework", "sb3", "--checkpoint",
                  str(checkpoint), "--max-iterations", "3"],
                 ["train", "--task", "cartpole", "--framework", "sb3", "--checkpoint",
                  str(run_dir), "--max-iterations", "4"],
                 ["train", "--task", "cartpole", "--framework", "sb3", "--checkpoint", "latest",
                  "--max-iterations", "5"]):
        plant_sb3_payload(run_dir / sorted(p.name for p in run_dir.glob("model_*.zip"))[-1],
                          marker)
        result = lab(*args, logs=logs)
        assert result.exit_code == 0, (args, result.output)  # the tensors are fine: it works
        assert not marker.exists(), f"lab {' '.join(args)} ran the payload"


def test_a_pickled_vecnormalize_is_refused_and_runs_no_code(tmp_path):
    logs = tmp_path / "logs"
    run_dir = train(logs, "sb3")
    marker = tmp_path / "marker"
    (run_dir / "vecnormalize_2.json").unlink()
    (run_dir / "vecnormalize_2.pkl").write_bytes(pickle.dumps(Payload(marker)))
    remanifest(run_dir, 2)
    for args in (["play", "--run", str(run_dir)], ["export", "onnx", "--run", str(run_dir)],
                 ["train", "--task", "cartpole", "--framework", "sb3", "--checkpoint",
                  "latest", "--max-iterations", "3"]):
        result = lab(*args, logs=logs)
        assert_one_line_error(result, "vecnormalize_2.pkl is a pickle, which lab does not load")
        assert not marker.exists()


@pytest.mark.parametrize("framework, target", [("rsl_rl", "model_2.pt"), ("skrl", "model_2.pt"),
                                               ("sb3", "state_2.pt")])
def test_torch_files_with_a_pickled_payload_run_no_code(framework, target, tmp_path):
    logs = tmp_path / "logs"
    run_dir = train(logs, framework)
    marker = tmp_path / "marker"
    torch.save({"payload": Payload(marker)}, run_dir / target)
    with contextlib.suppress(Exception):
        torch.load(run_dir / target, weights_only=False)  # an unsafe load runs it
    assert marker.exists()
    marker.unlink()
    remanifest(run_dir, 2)
    args = (["train", "--task", "cartpole", "--framework", framework, "--checkpoint", "latest",
             "--max-iterations", "3"] if target.startswith("state") else ["play", "--last"])
    result = lab(*args, logs=logs)
    assert_one_line_error(result, target)
    assert not marker.exists()


# Links ---------------------------------------------------------------------------------------
def test_export_replaces_a_planted_link_and_does_not_write_its_target(tmp_path):
    logs = tmp_path / "logs"
    run_dir = train(logs, "rsl_rl")
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (run_dir / "exported").mkdir()
    (run_dir / "exported" / "policy.onnx").symlink_to(victim)
    (run_dir / "exported" / "policy.onnx.json").symlink_to(victim)
    assert lab("export", "onnx", "--run", str(run_dir), logs=logs).exit_code == 0
    assert victim.read_text() == "precious"
    for name in ("policy.onnx", "policy.onnx.json"):
        assert not (run_dir / "exported" / name).is_symlink()


@pytest.mark.parametrize("planted", ["exported", "params", "videos"])
def test_a_linked_directory_in_a_run_dir_is_refused_before_writing(planted, tmp_path):
    logs = tmp_path / "logs"
    run_dir = train(logs, "rsl_rl")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    if planted == "params":  # the run's params move behind a link
        shutil.copytree(run_dir / "params", elsewhere, dirs_exist_ok=True)
        shutil.rmtree(run_dir / "params")
    (run_dir / planted).symlink_to(elsewhere, target_is_directory=True)
    before = sorted(p.name for p in elsewhere.iterdir())
    args = {"exported": ["export", "onnx", "--run", str(run_dir)],
            "params": ["train", "--task", "cartpole", "--framework", "rsl_rl", "--checkpoint",
                       "latest", "--max-iterations", "3"],
            "videos": ["train", "--task", "cartpole", "--framework", "rsl_rl", "--checkpoint",
                       "latest", "--max-iterations", "3", "--video", "--video-length", "4"]}
    result = lab(*args[planted], logs=logs)
    assert_one_line_error(result, f"{planted} is a symbolic link")
    assert sorted(p.name for p in elsewhere.iterdir()) == before


def test_resume_removes_planted_candidate_links_without_following_them(tmp_path):
    logs = tmp_path / "logs"
    run_dir = train(logs, "skrl")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "keep.txt").write_text("precious")
    for name in (".candidate", ".good"):
        (run_dir / name).symlink_to(elsewhere, target_is_directory=True)
    result = lab("train", "--task", "cartpole", "--framework", "skrl", "--checkpoint", "latest",
                 "--max-iterations", "4", logs=logs)
    assert result.exit_code == 0, result.output
    assert (elsewhere / "keep.txt").read_text() == "precious"
    assert sorted(p.name for p in elsewhere.iterdir()) == ["keep.txt"]


# Names and paths -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["x/../../../../escaped", "../../x", "/tmp/abs", "a/b",
                                  "x" * 300, ".hidden", "-rf", "a b"])
def test_a_run_name_is_one_plain_path_component(name, tmp_path):
    logs = tmp_path / "logs" / "deep"
    result = lab("train", "--task", "cartpole", "--framework", "rsl_rl", "--num-envs", "4",
                 "--max-iterations", "1", "--run-name", name, logs=logs)
    assert_one_line_error(result, "--run-name", "is not a plain name")
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing made, anywhere


def test_a_run_name_with_brackets_is_fine(tmp_path):
    result = lab("train", "--task", "cartpole", "--framework", "rsl_rl", "--num-envs", "4",
                 "--max-iterations", "1", *SMALL["rsl_rl"], "--run-name", "[bold]", logs=tmp_path)
    assert result.exit_code == 0, result.output
    assert [p.name.endswith("_[bold]") for p in tmp_path.glob("rsl_rl/cartpole/*")] == [True]


@contextlib.contextmanager
def read_only(path: Path) -> Iterator[None]:
    """`path` made read-only for this process: by permissions, or, as root (whom permissions do
    not stop), by a read-only bind mount onto itself; skipped where neither works."""
    if os.geteuid() != 0:
        modes = {p: p.stat().st_mode for p in [path, *path.rglob("*")] if not p.is_symlink()}
        for p in modes:
            p.chmod(modes[p] & ~0o222)
        try:
            yield
        finally:
            for p, mode in modes.items():
                p.chmod(mode)
        return
    mounted = subprocess.run(["mount", "--bind", str(path), str(path)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot make {path} read-only here: {mounted.stderr.decode().strip()}")
    try:
        remounted = subprocess.run(["mount", "-o", "remount,bind,ro", str(path)],
                                   capture_output=True)
        if remounted.returncode != 0:
            pytest.skip(f"cannot remount {path} read-only: {remounted.stderr.decode().strip()}")
        yield
    finally:
        subprocess.run(["umount", str(path)], check=True)


def test_plot_to_a_place_that_cannot_be_written_is_one_line(tmp_path):
    logs = tmp_path / "logs"
    train(logs, "rsl_rl")
    (tmp_path / "a_file").write_text("")
    locked = tmp_path / "locked"
    locked.mkdir()
    tag = ["--metric", "Perf/steps_per_s"]  # logged from the first iteration on
    for output in ("/proc/x.png", str(tmp_path / "a_file" / "x.png")):
        assert_one_line_error(lab("plot", *tag, "-o", output, logs=logs), "cannot write")
    with read_only(locked):
        assert_one_line_error(lab("plot", *tag, "-o", str(locked / "x.png"), logs=logs),
                              "cannot write")
    assert not list(locked.iterdir())


def test_export_from_a_read_only_run_and_videos_into_read_only_logs_are_one_line(tmp_path):
    logs = tmp_path / "logs"
    run_dir = train(logs, "rsl_rl")
    with read_only(logs):
        assert_one_line_error(lab("export", "onnx", "--run", str(run_dir), logs=logs),
                              "cannot write")
        assert_one_line_error(lab("play", "--agent", "random", "--task", "cartpole", "--video",
                                  "--episodes", "1", "--video-length", "4", logs=logs),
                              "cannot write")
    assert not (run_dir / "exported").exists() and not (logs / "sanity").exists()


@pytest.mark.parametrize("gym_id", ["phys2d/CartPole-v1", "tabular/Blackjack-v0"])
def test_a_gym_id_whose_module_cannot_be_imported_is_one_line(gym_id, tmp_path):
    pytest.importorskip("gymnasium")
    if __import__("importlib").util.find_spec("jax") is not None:
        pytest.skip("jax is installed here")
    for args in (["train", "--task", f"gym:{gym_id}", "--framework", "sb3"],
                 ["play", "--agent", "random", "--task", f"gym:{gym_id}"]):
        assert_one_line_error(lab(*args, logs=tmp_path), gym_id, "cannot be imported")
    assert not list(tmp_path.iterdir())


def test_bench_refuses_counts_and_seconds_that_cannot_work(tmp_path):
    assert_one_line_error(lab("bench", "--task", "cartpole", "--num-envs", "100000000",
                              logs=tmp_path), "env.num_envs")
    assert_one_line_error(lab("bench", "--task", "cartpole", "--seconds", "-1", logs=tmp_path),
                          "--seconds")


# Files a run's params name -----------------------------------------------------------------------
GYM = "gym:InvertedPendulum-v5"
GYM_SMALL = ["--num-envs", "2", "--set", "agent.n_steps=8", "--set", "agent.batch_size=16",
             "--set", "agent.n_epochs=1"]


def train_gym(logs: Path, *extra: str) -> Path:
    result = lab("train", "--task", GYM, "--framework", "sb3", "--max-iterations", "1",
                 *GYM_SMALL, *extra, logs=logs)
    assert result.exit_code == 0, result.output
    (run_dir,) = logs.glob("sb3/*/*")
    return run_dir


@pytest.fixture(scope="module")
def gym_run(tmp_path_factory) -> Path:
    return train_gym(tmp_path_factory.mktemp("gym_logs"))


@pytest.fixture
def opened(monkeypatch) -> list[str]:
    """The model files gymnasium's MuJoCo envs are asked to open."""
    from gymnasium.envs.mujoco import mujoco_env

    paths: list[str] = []
    expand = mujoco_env.expand_model_path
    monkeypatch.setattr(mujoco_env, "expand_model_path",
                        lambda path: paths.append(path) or expand(path))
    return paths


def with_env_kwargs(run_dir: Path, kwargs: dict) -> None:
    params = run_dir / "params" / "env.yaml"
    params.write_text(params.read_text().replace("kwargs: {}", f"kwargs: {json.dumps(kwargs)}"))


@pytest.mark.parametrize("planted", ["/etc/passwd", "/dev/zero", "MJCF", "./model.xml",
                                     "~/.ssh/id_rsa", ["/etc/passwd"]])
def test_a_run_whose_env_kwargs_name_a_file_is_refused_before_it_is_opened(planted, gym_run,
                                                                         opened, tmp_path):
    run_dir = Path(shutil.copytree(gym_run, tmp_path / "logs" / "sb3" / GYM / "run"))
    if planted == "MJCF":  # inside the run dir, including a system file
        (run_dir / "model.xml").write_text('<mujoco><include file="/etc/passwd"/></mujoco>')
        planted = str(run_dir / "model.xml")
    with_env_kwargs(run_dir, {"xml_file": planted})
    before = sorted(p.name for p in run_dir.iterdir())
    for args in (["play", "--run", str(run_dir), "--episodes", "1"],
                 ["export", "onnx", "--run", str(run_dir)],
                 ["train", "--task", GYM, "--framework", "sb3", "--checkpoint", str(run_dir),
                  "--max-iterations", "2"]):
        assert_one_line_error(lab(*args, logs=tmp_path / "logs"), "params/env.yaml",
                              "env.kwargs.xml_file", "names the file",
                              "lab opens no file that a run dir names",
                              "if you trust it, pass it yourself: --set")
    assert opened == []
    assert sorted(p.name for p in run_dir.iterdir()) == before


@pytest.mark.parametrize(("value", "path"), [
    ("/etc/passwd", True), ("./model.xml", True), ("a/b", True), ("~", True), ("~/x", True),
    (".", True), ("..", True), (b"/dev/zero", True),
    ("ant.xml", False), (".*_foot", False), ("leg_\\d", False), ("", False), (3, False)])
def test_a_setting_names_a_file_by_its_path_not_by_a_bare_name_or_pattern(value, path):
    from labcli.runs.config import names_a_file

    assert names_a_file(value) is path


def test_no_task_s_own_settings_are_taken_for_files():
    """A robot task's term settings hold patterns of body names (".*_foot"), not paths."""
    from labcli.plugins import registry
    from labcli.runs.config import check_saved

    for name in registry.loaded().names("task"):
        model = registry.get_task(name).config_class
        check_saved(model, "env", Path("params/env.yaml"), model().model_dump(mode="json"))


def test_a_file_the_user_names_this_time_is_used(tmp_path, opened):
    from gymnasium.envs.mujoco import mujoco_env

    model = tmp_path / "pendulum.xml"
    shutil.copy(Path(mujoco_env.__file__).parent / "assets" / "inverted_pendulum.xml", model)
    logs = tmp_path / "logs"
    run_dir = train_gym(logs, "--set", f"env.kwargs.xml_file={model}")
    assert set(opened) == {str(model)}
    count = len(opened)
    mine = ["--set", f"env.kwargs.xml_file={model}"]
    # The run's own params name it: played, exported or resumed only when named again.
    play = ["play", "--run", str(run_dir), "--episodes", "1"]
    resume = ["train", "--task", GYM, "--framework", "sb3", "--checkpoint", "latest",
              "--max-iterations", "2"]
    export = ["export", "onnx", "--run", str(run_dir)]
    for args in (play, export, resume):
        assert_one_line_error(lab(*args, logs=logs), f"env.kwargs.xml_file names the file "
                              f"'{model}'", f"--set env.kwargs.xml_file={model}")
    assert len(opened) == count
    for args in (play, export, resume):
        result = lab(*args, *mine, logs=logs)
        assert result.exit_code == 0, result.output
        assert len(opened) > count and set(opened) == {str(model)}
        count = len(opened)
    # A play still sets nothing else of the run's settings.
    assert_one_line_error(lab(*play, "--set", "env.kwargs.frame_skip=3", logs=logs),
                          "--set env.kwargs.frame_skip cannot change a run",
                          "may set: env.kwargs.xml_file")
    # A file of the user's that is no model is one line too.
    assert_one_line_error(lab("train", "--task", GYM, "--framework", "sb3", *GYM_SMALL, "--set",
                              "env.kwargs.xml_file=/etc/passwd", logs=tmp_path / "other"),
                          "gymnasium could not make 'InvertedPendulum-v5'")
