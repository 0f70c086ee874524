"""MuJoCo Menagerie's robots through a run's life, with the real `mujoco-menagerie` package and
the offline copy of its folders (MENAGERIE_ROOT): the model a run records and that play, export
and resume rebuild, what `lab info`, `lab config show` and `lab list` say of it, the download's
progress, and the one-line errors when a robot can be neither found nor downloaded."""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import http.server
import io
import json
import os
import shutil
import subprocess
import sys
import tarfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import mujoco
import mujoco_menagerie as mm
import pytest
from conftest import needs_menagerie
from installed import on_sys_path
from oneline import assert_one_line_error
from rich.console import Console
from typer.testing import CliRunner

from labcli.commands.app import app
from labcli.envs import models
from labcli.envs.spec import Menagerie, TaskSpec
from labcli.plugins import registry
from labcli.plugins.hookspecs import hookimpl
from labcli.runs import play, rundir, training

TASK, DIST, MODULE = "menagerie-go1", "lab-menagerie-go1", "lab_menagerie_go1"
SCENE, BARE = Menagerie("unitree_go1", "scene"), Menagerie("unitree_go1", "go1")
# A task plugin whose model is Menagerie's Go1 by name: a small standing task made of existing
# terms, installed as a distribution (dist-info with its entry point) so that a `lab` started
# in a subprocess finds it too.
PLUGIN = f'''
from pydantic import Field

from labcli.envs.mdp import config as c
from labcli.envs.spec import Menagerie, TaskSpec
from labcli.plugins.hookspecs import hookimpl


class Observations(c.Group):
    projected_gravity: c.ProjectedGravity | None = c.ProjectedGravity()
    joint_pos: c.JointPos | None = c.JointPos()
    joint_vel: c.JointVel | None = c.JointVel(scale=0.05)


class Rewards(c.Group):
    alive: c.Alive | None = c.Alive(weight=1.0)
    action_rate: c.ActionRateL2 | None = c.ActionRateL2(weight=-0.01)


class Go1Config(c.RobotTaskConfig):
    num_envs: int = Field(4, gt=0)
    episode_length_s: float = Field(0.2, gt=0)
    decimation: int = Field(4, gt=0)
    actions: c.JointPosition = c.JointPosition(scale=0.25)
    observations: Observations = Observations()
    rewards: Rewards = Rewards()


MODEL = Menagerie({SCENE.robot!r}, {SCENE.entry!r})  # a test may change it


@hookimpl
def register_tasks(register):
    register(TaskSpec(name={TASK!r}, task="labcli.envs.mdp.task:RobotTask",
                      config="{MODULE}:Go1Config", model=MODEL,
                      description="Menagerie's Go1 standing"))
'''
SB3 = ["agent.n_steps=8", "agent.batch_size=16", "agent.n_epochs=1", "agent.net_arch=[16]"]
OFFLINE = {"MENAGERIE_ROOT": None}  # CliRunner's env: unset


def write_plugin(site: Path) -> Path:
    site.mkdir(parents=True, exist_ok=True)
    (site / f"{MODULE}.py").write_text(PLUGIN)
    info = site / f"{MODULE}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {DIST}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[lab]\nmenagerie_go1 = {MODULE}\n")
    return site


@pytest.fixture
def plugin(tmp_path) -> Iterator[ModuleType]:
    """The task installed for this test; its module, whose MODEL a test may change (then
    `registry.reload()`)."""
    with on_sys_path(write_plugin(tmp_path / "site")):
        registry.reload()
        assert TASK in registry.loaded().names(registry.TASK), registry.loaded().failures
        yield sys.modules[MODULE]


def lab(*args: str, logs: Path, **env: str | None):
    return CliRunner().invoke(app, [*args], env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "300",
                                                  **env})


def train(logs: Path, iterations: int = 1, checkpoint: str | None = None,
          console: Console | None = None):
    return training.train(TASK, "sb3", max_iterations=iterations, overrides=SB3, logs_dir=logs,
                          checkpoint=checkpoint, console=console or Console(file=io.StringIO()),
                          command=["lab", "test"])


def set_model(plugin: ModuleType, monkeypatch: pytest.MonkeyPatch, model: Menagerie | Path
              ) -> None:
    """The task's spec names `model` from now on, as a new version of its package would."""
    monkeypatch.setattr(plugin, "MODEL", model)
    registry.reload()
    assert registry.get_task(TASK).model == model


def geom_names(env) -> set[str]:
    model = env.sim.model
    return {mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, i) for i in range(model.ngeom)}


# The run's record, and what play, export and resume rebuild from it --------------------------

@needs_menagerie("unitree_go1")
def test_a_run_records_its_model_and_play_export_resume_rebuild_it(plugin, monkeypatch,
                                                                   tmp_path, capsys):
    run = train(tmp_path).run
    recorded = json.loads((run.dir / rundir.MANIFEST).read_text())["model"]["menagerie"]
    robot = mm.get("unitree_go1")
    assert recorded == {"robot": "unitree_go1", "entry": "scene", "package": mm.__version__,
                        "commit": mm.commit(), "tree": robot.oid,
                        "root": os.environ["MENAGERIE_ROOT"]}

    # A later version of the task names another entry: the bare robot, without scene.xml's
    # floor. The run's policy still fits it (the same joints), so nothing but the record
    # keeps play on the model the run trained on.
    set_model(plugin, monkeypatch, BARE)
    loaded = play.load(run_dir=run.dir, num_envs=2)
    try:
        assert loaded.spec.model == SCENE
        assert "floor" in geom_names(loaded.env)
    finally:
        loaded.env.close()
    sanity_spec = registry.get_task(TASK)  # a task without a run: the task's model
    assert sanity_spec.model == BARE

    exported = lab("export", "onnx", "--run", str(run.dir), logs=tmp_path)
    assert exported.exit_code == 0, exported.output
    meta = json.loads((run.dir / "exported" / "policy.onnx.json").read_text())
    assert meta["model"]["menagerie"]["entry"] == "scene"

    resumed = train(tmp_path, iterations=2, checkpoint=str(run.dir))
    assert resumed.run.dir == run.dir and resumed.summary["iterations"] == 2
    manifest = json.loads((run.dir / rundir.MANIFEST).read_text())
    assert manifest["model"]["menagerie"]["entry"] == "scene"
    assert "warning" not in capsys.readouterr().err  # the folder is the recorded one


@needs_menagerie("unitree_go1")
def test_a_model_that_changed_since_the_run_is_one_warning_line(plugin, tmp_path):
    run = train(tmp_path).run
    manifest = json.loads((run.dir / rundir.MANIFEST).read_text())
    manifest["model"]["menagerie"].update(tree="0" * 40, package="2026.1.1")
    (run.dir / rundir.MANIFEST).write_text(json.dumps(manifest))

    played = lab("play", "--run", str(run.dir), "--episodes", "1", logs=tmp_path)
    assert played.exit_code == 0, played.output
    (warning,) = [line for line in played.stderr.splitlines() if "warning" in line]
    assert warning.startswith("warning: MuJoCo Menagerie's unitree_go1 may have changed")
    assert "000000000000 (mujoco-menagerie 2026.1.1)" in warning
    assert mm.get("unitree_go1").oid[:12] in warning

    info = lab("info", "--run", str(run.dir), logs=tmp_path)
    assert info.exit_code == 0, info.output
    assert "may have changed" in info.stdout and "mujoco-menagerie 2026.1.1" in info.stdout

    said = io.StringIO()
    train(tmp_path, iterations=2, checkpoint=str(run.dir), console=Console(file=said))
    resumed, warned = said.getvalue().splitlines()[:2]
    assert resumed.startswith(f"resume {run.dir}") and warned == warning
    # The session that resumed it trained on the folder here, and records that one.
    manifest = json.loads((run.dir / rundir.MANIFEST).read_text())
    assert manifest["model"]["menagerie"]["tree"] == mm.get("unitree_go1").oid


class FileTask:
    """A second task whose model is `file`: a task of an installed plugin names it."""

    def __init__(self, file: Path):
        self.file = file

    @hookimpl
    def register_tasks(self, register):
        register(TaskSpec(name="file-go1", task="labcli.envs.mdp.task:RobotTask",
                          config=f"{MODULE}:Go1Config", model=self.file,
                          description="Menagerie's Go1 standing, from a file"))


@needs_menagerie("unitree_go1")
def test_a_run_on_a_model_file_plays_on_it_while_an_installed_task_names_it(
        plugin, monkeypatch, tmp_path, register_plugin):
    """go1-flat's own story: its model was a file of lab's (go1-rough's still), now it is
    Menagerie's. Its earlier runs play on their file while an installed task names it; a path
    no installed task names is never opened (a run dir is data): the task's current model,
    with one warning line."""
    folder = tmp_path / "go1"
    shutil.copytree(Path(os.environ["MENAGERIE_ROOT"]) / "unitree_go1", folder)
    file = folder / "scene.xml"
    set_model(plugin, monkeypatch, file)
    run = train(tmp_path).run
    assert json.loads((run.dir / rundir.MANIFEST).read_text())["model"] == {
        "file": str(file), "sha256": hashlib.sha256(file.read_bytes()).hexdigest()}

    set_model(plugin, monkeypatch, BARE)
    register_plugin(FileTask(file), "file-go1")
    loaded = play.load(run_dir=run.dir, num_envs=2)
    try:
        assert loaded.spec.model == file and "floor" in geom_names(loaded.env)
    finally:
        loaded.env.close()

    registry.pm.unregister(name="file-go1")
    registry.reload()
    played = lab("play", "--run", str(run.dir), "--episodes", "1", logs=tmp_path)
    assert played.exit_code == 0, played.output
    (warning,) = [line for line in played.stderr.splitlines() if "warning" in line]
    assert warning.startswith(f"warning: the run's model {file} is no installed task's model "
                              "(lab opens no other file a run names): its env is built on the "
                              "task's current model, MuJoCo Menagerie's unitree_go1")


@needs_menagerie("unitree_go1")
def test_a_run_from_another_host_plays_silently_on_the_task_s_file_of_its_content(
        plugin, monkeypatch, tmp_path):
    """A run trained on a GPU host names the file where that host installed the task: here the
    task's file of the content the run recorded is its model, without a word; the file edited
    since, the one warning line."""
    folder = tmp_path / "go1"
    shutil.copytree(Path(os.environ["MENAGERIE_ROOT"]) / "unitree_go1", folder)
    file = folder / "scene.xml"
    set_model(plugin, monkeypatch, file)
    run = train(tmp_path).run
    manifest = json.loads((run.dir / rundir.MANIFEST).read_text())
    elsewhere = "/root/site-packages/lab_menagerie_go1/scene.xml"
    manifest["model"]["file"] = elsewhere
    (run.dir / rundir.MANIFEST).write_text(json.dumps(manifest))
    played = lab("play", "--run", str(run.dir), "--episodes", "1", logs=tmp_path)
    assert played.exit_code == 0, played.output
    assert "warning" not in played.stderr

    file.write_text(file.read_text() + "<!-- edited -->\n")
    played = lab("play", "--run", str(run.dir), "--episodes", "1", logs=tmp_path)
    assert played.exit_code == 0, played.output
    (warning,) = [line for line in played.stderr.splitlines() if "warning" in line]
    assert warning.startswith(f"warning: the run's model {elsewhere} is no installed task's "
                              f"model (lab opens no other file a run names): its env is built "
                              f"on the task's current model, {file}")


@pytest.mark.parametrize("model", [{"menagerie": {"robot": 5, "entry": "scene"}},
                                   {"menagerie": "unitree_go1"}, ["unitree_go1"]])
def test_a_damaged_model_record_is_one_line(plugin, tmp_path, model):
    run = rundir.create(tmp_path, "sb3", TASK)
    rundir.write_json(run.dir, rundir.MANIFEST, {"task": TASK, "framework": "sb3",
                                                 "model": model})
    for command in (["play", "--run", str(run.dir)], ["info", "--run", str(run.dir)]):
        assert_one_line_error(lab(*command, logs=tmp_path), str(run.dir / rundir.MANIFEST),
                              "damaged")


# What lab info, config show and list say, without downloading ---------------------------------

def test_info_config_show_and_list_name_the_model(plugin, tmp_path):
    root = os.environ.get("MENAGERIE_ROOT")
    info = lab("info", "--task", TASK, logs=tmp_path)
    assert info.exit_code == 0, info.output
    for phrase in ("MuJoCo Menagerie's unitree_go1 (Unitree Go1), entry scene (scene.xml)",
                   f"mujoco-menagerie {mm.__version__}: Menagerie commit {mm.commit()[:12]}",
                   f"unitree_go1 folder {mm.get('unitree_go1').oid[:12]}"):
        assert phrase in info.stdout
    if root:
        assert f"{Path(root) / 'unitree_go1'} (MENAGERIE_ROOT)" in info.stdout

    shown = lab("config", "show", "--task", TASK, "--framework", "sb3", logs=tmp_path)
    assert shown.exit_code == 0, shown.output
    first = shown.stdout.splitlines()[0]
    assert first.startswith("# model: MuJoCo Menagerie's unitree_go1 (Unitree Go1), entry scene")
    assert f"mujoco-menagerie {mm.__version__}" in first

    listed = lab("list", logs=tmp_path).stdout
    assert "model: menagerie:unitree_go1/scene" in listed_row(listed, TASK)
    assert "model: cartpole.xml" in listed_row(listed, "cartpole")


def listed_row(listed: str, name: str) -> str:
    """The lines of `lab list`'s row for `name`: its own and the indented ones after it."""
    lines = listed.splitlines()
    start = next(i for i, line in enumerate(lines) if line.split()[:1] == [name])
    end = next((i for i in range(start + 1, len(lines))
                if lines[i][:2].strip()), len(lines))
    return "\n".join(lines[start:end])


def test_info_says_where_the_files_would_come_from_and_downloads_nothing(plugin, tmp_path):
    cache = tmp_path / "cache"
    info = lab("info", "--task", TASK, logs=tmp_path, MENAGERIE_CACHE_DIR=str(cache),
               MENAGERIE_BASE_URL="http://127.0.0.1:1", **OFFLINE)
    assert info.exit_code == 0, info.output
    size = models.mebibytes(mm.get("unitree_go1").download_size)
    assert f"not cached yet: a {size} download into {cache} on first use" in info.stdout
    assert not cache.exists()

    elsewhere = tmp_path / "copy"
    elsewhere.mkdir()
    info = lab("info", "--task", TASK, logs=tmp_path, MENAGERIE_ROOT=str(elsewhere))
    assert f"none: MENAGERIE_ROOT={elsewhere} has no folder unitree_go1" in info.stdout


# One line for every way a robot cannot be had ---------------------------------------------

@pytest.mark.parametrize("model, phrases", [
    (Menagerie("unitree_g2", "scene"), ["MuJoCo Menagerie has no robot 'unitree_g2'",
                                        "did you mean 'unitree_go2'?"]),
    (Menagerie("unitree_go1", "scene_mjx"), ["MuJoCo Menagerie's unitree_go1 has no entry "
                                             "'scene_mjx'", "its entries: go1, scene"]),
])
def test_an_unknown_robot_or_entry_is_one_line(plugin, monkeypatch, tmp_path, model, phrases):
    set_model(plugin, monkeypatch, model)
    for command in (["play", "--agent", "zero", "--task", TASK], ["info", "--task", TASK],
                    ["config", "show", "--task", TASK, "--framework", "sb3"]):
        assert_one_line_error(lab(*command, logs=tmp_path), *phrases)


def test_a_menagerie_root_without_the_robot_is_one_line(plugin, tmp_path):
    elsewhere = tmp_path / "copy"
    (elsewhere / "unitree_g1").mkdir(parents=True)
    result = lab("play", "--agent", "zero", "--task", TASK, logs=tmp_path,
                 MENAGERIE_ROOT=str(elsewhere))
    assert_one_line_error(result, f"MENAGERIE_ROOT={elsewhere} has no folder unitree_go1",
                          "unset MENAGERIE_ROOT", "MENAGERIE_CACHE_DIR")


def test_a_cache_that_cannot_be_written_is_one_line(plugin, tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")  # a folder below a file cannot be made, even by root
    result = lab("play", "--agent", "zero", "--task", TASK, logs=tmp_path,
                 MENAGERIE_CACHE_DIR=str(blocker / "cache"), **OFFLINE)
    assert_one_line_error(result, f"MuJoCo Menagerie's cache {blocker / 'cache'} cannot be "
                          "written", "set MENAGERIE_CACHE_DIR to a writable folder",
                          "MENAGERIE_ROOT")


def test_no_network_and_no_copy_is_one_line_exit_2(tmp_path):
    """Through the command line, as a user meets it: an empty cache, no MENAGERIE_ROOT and a
    download that cannot connect (the package tries three times, 7 s of waits)."""
    site = write_plugin(tmp_path / "site")
    env = {key: value for key, value in os.environ.items() if key != "MENAGERIE_ROOT"}
    env.update(PYTHONPATH=os.pathsep.join(filter(None, [str(site), env.get("PYTHONPATH")])),
               MENAGERIE_CACHE_DIR=str(tmp_path / "cache"),
               MENAGERIE_BASE_URL="http://127.0.0.1:1", LAB_LOGS_DIR=str(tmp_path / "logs"))
    started = time.monotonic()
    result = subprocess.run([sys.executable, "-m", "labcli", "train", "--task", TASK,
                             "--framework", "sb3"], capture_output=True, text=True, env=env,
                            timeout=60)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    announced, downloading, error = result.stderr.splitlines()
    assert announced.startswith(f"train {TASK} with sb3")
    assert downloading.startswith("downloading MuJoCo Menagerie's unitree_go1 (")
    assert error.startswith("error: MuJoCo Menagerie's unitree_go1 is not in the cache")
    for phrase in ("could not be downloaded", "Connection refused",
                   "connect to the internet once", "MENAGERIE_CACHE_DIR", "MENAGERIE_ROOT"):
        assert phrase in error
    assert not (tmp_path / "logs").exists()  # nothing written
    assert time.monotonic() - started < 30


# The download's progress ---------------------------------------------------------------------

@contextlib.contextmanager
def serving(folder: Path) -> Iterator[str]:
    """An HTTP server of `folder`'s files on localhost, as Menagerie's releases page; its URL."""

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, directory=str(folder), **kwargs)

        def log_message(self, *args) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


@pytest.fixture
def small_release(tmp_path, monkeypatch) -> tuple[str, mm.Robot]:
    """A release archive of a small stand-in for unitree_go1 (a box on a plane, 2 MiB of
    padding so that the download takes several chunks) served on localhost, and the registry's
    entry for it: its digest and size are this archive's."""
    import hashlib

    folder = tmp_path / "release" / "unitree_go1"
    folder.mkdir(parents=True)
    (folder / "scene.xml").write_text('<mujoco><worldbody><geom name="floor" type="plane" '
                                      'size="1 1 .1"/><body><freejoint/><geom type="box" '
                                      'size=".1 .1 .1"/></body></worldbody></mujoco>')
    (folder / "padding.bin").write_bytes(os.urandom(2 * 2**20))
    real = mm.get("unitree_go1")
    archive = tmp_path / "release" / real.asset
    with tarfile.open(archive, "w:xz", preset=0) as tar:
        tar.add(folder, arcname="unitree_go1")
    data = archive.read_bytes()
    robot = dataclasses.replace(real, sha256=hashlib.sha256(data).hexdigest(),
                                download_size=len(data))
    monkeypatch.setattr(mm, "get", lambda name: robot if name == "unitree_go1" else real)
    monkeypatch.delenv("MENAGERIE_ROOT", raising=False)
    monkeypatch.setenv("MENAGERIE_CACHE_DIR", str(tmp_path / "cache"))
    return str(tmp_path / "release"), robot


def test_a_download_says_when_it_starts_and_ends_once_off_a_terminal(small_release, tmp_path,
                                                                    monkeypatch, capsys):
    release, robot = small_release
    with serving(Path(release)) as url:
        monkeypatch.setenv("MENAGERIE_BASE_URL", url)
        path = models.menagerie_xml(SCENE)
        lines = capsys.readouterr().err.splitlines()
        assert path == mm.Cache().model_path(robot) / "scene.xml" and path.is_file()
        size = models.mebibytes(robot.download_size)
        assert lines == [
            f"downloading MuJoCo Menagerie's unitree_go1 ({size}) from {url} into "
            f"{tmp_path / 'cache'}",
            f"downloaded MuJoCo Menagerie's unitree_go1 into {path.parent}"]
        assert models.menagerie_xml(SCENE) == path  # cached: nothing said
        assert capsys.readouterr().err == ""


def test_a_download_on_a_terminal_is_one_transient_bar_in_mib(small_release, monkeypatch):
    release, robot = small_release
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=120)
    with serving(Path(release)) as url:
        cache = mm.Cache(base_url=url)
        with models.DownloadProgress(robot, cache, console) as progress:
            calls = []
            folder = robot.path(cache, progress=lambda *a: (calls.append(a), progress(*a)))
    assert (folder / "scene.xml").is_file() and len(calls) >= 2
    assert calls[-1][1:] == (robot.download_size, robot.download_size)
    text = out.getvalue()
    assert "downloading MuJoCo Menagerie's unitree_go1" in text and "MiB" in text
    assert "downloaded" not in text  # transient: the bar goes, no line stays
