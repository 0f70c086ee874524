"""Nothing lost, nothing hidden (docs/robustness.md): resumes are all-or-nothing, checkpoints and
exports whole or absent, a full disk and damaged files are one line that leaves the good runs
and checkpoints usable, a run has one writer, and signals never end in a traceback."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
import zipfile
from pathlib import Path

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from oneline import assert_one_line_error
from runfiles import kill_when_writing, remanifest, snapshot_of
from typer.testing import CliRunner

from labcli import files, testing
from labcli.commands.app import app
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.runs import checkpoints, rundir

SMALL = {name: [part for item in items for part in ("--set", item)]
         for name, items in testing.SMALL_AGENTS.items()}
FRAMEWORKS = list(SMALL)


def lab(*args: str, logs: Path):
    return CliRunner().invoke(app, list(args), env={"LAB_LOGS_DIR": str(logs), "COLUMNS": "300"})


def train(logs: Path, framework: str, *extra: str, iterations: int = 2):
    result = lab("train", "--task", "cartpole", "--framework", framework, "--num-envs", "4",
                 "--max-iterations", str(iterations), "--set", "agent.save_interval=1",
                 *SMALL[framework], *extra, logs=logs)
    assert result.exit_code == 0, result.output
    return max(logs.glob(f"{framework}/cartpole/*"), key=lambda p: p.name)


def resume(logs: Path, framework: str, iterations: int, *extra: str):
    return lab("train", "--task", "cartpole", "--framework", framework, "--checkpoint",
               "latest", "--max-iterations", str(iterations), *extra, logs=logs)


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> dict[str, Path]:
    """A small finished run of each framework, checkpoints 1 and 2, for tests that only read."""
    logs = tmp_path_factory.mktemp("logs")
    return {framework: train(logs, framework) for framework in FRAMEWORKS}


def fresh_copy(run_dir: Path, tmp_path: Path) -> tuple[Path, Path]:
    """A copy of a trained run in `tmp_path`/logs: (logs, run dir)."""
    logs = tmp_path / "logs"
    target = logs / run_dir.relative_to(run_dir.parents[2])
    shutil.copytree(run_dir, target, symlinks=True)
    return logs, target


# Resume: all or nothing -----------------------------------------------------------------------
REFUSED = {"sb3": "agent.net_arch=[8]", "sb3_sac": "agent.net_arch=[8]",
           "sb3_td3": "agent.net_arch=[8]", "rsl_rl": "agent.actor_hidden_dims=[8]",
           "skrl": "agent.hidden_sizes=[8]", "skrl_sac": "agent.hidden_sizes=[8]",
           "skrl_td3": "agent.hidden_sizes=[8]", "rl_games": "agent.units=[8]"}


@pytest.mark.parametrize("framework", FRAMEWORKS)
def test_a_refused_resume_writes_nothing_and_the_run_resumes_after(framework, trained,
                                                                   tmp_path):
    logs, run_dir = fresh_copy(trained[framework], tmp_path)
    before = snapshot_of(logs)
    for extra in (["--set", REFUSED[framework]], ["--set", "env.episode_length_s=2"],
                  ["--seed", "7"]):
        result = resume(logs, framework, 3, *extra)
        assert_one_line_error(result, "resuming model_2", "cannot change")
        assert snapshot_of(logs) == before
    assert resume(logs, framework, 3).exit_code == 0


def saved_learning_rate(framework: str, checkpoint: Path) -> float:
    """The learning rate in a checkpoint's optimizer state."""
    if framework.startswith("sb3"):  # SAC and TD3 save their actor's optimizer apart
        member = "policy.optimizer.pth" if framework == "sb3" else "actor.optimizer.pth"
        with zipfile.ZipFile(checkpoint) as archive, archive.open(member) as f:
            state = torch.load(f, weights_only=True)
    else:
        key = {"rsl_rl": "optimizer_state_dict", "skrl": "optimizer",
               "skrl_sac": "policy_optimizer", "skrl_td3": "policy_optimizer",
               "rl_games": "optimizer"}[framework]
        state = torch.load(checkpoint, weights_only=True)[key]
    return state["param_groups"][0]["lr"]


@pytest.mark.parametrize("framework", FRAMEWORKS)
def test_a_resume_applies_records_and_saves_what_it_may_change(framework, trained, tmp_path):
    logs, run_dir = fresh_copy(trained[framework], tmp_path)
    schedule = {"rsl_rl": ["--set", "agent.schedule=fixed"],
                "skrl": ["--set", "agent.kl_adaptive_lr=false"],
                "rl_games": ["--set", "agent.lr_schedule=constant"]}.get(framework, [])
    if schedule:  # an adaptive learning rate would move: start a run where it is fixed
        logs = tmp_path / "fixed"
        run_dir = train(logs, framework, *schedule)
    old = saved_learning_rate(framework, run_dir / checkpoints_name(framework, 2))
    result = resume(logs, framework, 3, "--set", "agent.learning_rate=1e-6", "--num-envs", "8")
    assert result.exit_code == 0, result.output
    assert "agent.learning_rate" in result.stderr  # the plan's line says what changes
    assert saved_learning_rate(framework, run_dir / checkpoints_name(framework, 3)) == 1e-6
    manifest = json.loads((run_dir / rundir.MANIFEST).read_text())
    assert manifest["sessions"][-1]["changed"] == {
        "agent.learning_rate": [old, 1e-6], "agent.max_iterations": [2, 3],
        "env.num_envs": [4, 8]}
    assert manifest["first_started"] == manifest["sessions"][0]["started"]
    assert "learning_rate: 1.0e-06" in (run_dir / rundir.AGENT_PARAMS).read_text()
    assert "num_envs: 8" in (run_dir / rundir.ENV_PARAMS).read_text()


def checkpoints_name(framework: str, iteration: int) -> str:
    return registry.get_framework(framework).checkpoint_path(Path(), iteration).name


def test_runs_shows_a_resumed_runs_first_start_and_total_wall_time(trained, tmp_path):
    logs, run_dir = fresh_copy(trained["rsl_rl"], tmp_path)
    first = json.loads((run_dir / rundir.SUMMARY).read_text())["wall_time_s"]
    started = json.loads((run_dir / rundir.MANIFEST).read_text())["started"]
    assert resume(logs, "rsl_rl", 3).exit_code == 0
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    (row,) = rundir.table(logs)
    assert row.started == started
    assert row.wall_time_s == summary["total_wall_time_s"] == pytest.approx(
        first + summary["wall_time_s"], abs=0.02)


# Checkpoints: complete or passed over -----------------------------------------------------------
def test_a_missing_normalizer_makes_its_checkpoint_incomplete(trained, tmp_path):
    logs, run_dir = fresh_copy(trained["sb3"], tmp_path)
    (run_dir / "vecnormalize_2.json").unlink()
    fw = registry.get_framework("sb3")
    assert checkpoints.latest_complete(fw, run_dir).iteration == 1
    for args in (["play", "--checkpoint", str(run_dir / "model_2.zip")],
                 ["export", "onnx", "--checkpoint", str(run_dir / "model_2.zip")]):
        assert_one_line_error(lab(*args, logs=logs),
                              "model_2.zip is incomplete: vecnormalize_2.json is missing")
    # A run dir with no complete checkpoint: the error says what its newest one lacks.
    (run_dir / "vecnormalize_1.json").unlink()
    assert_one_line_error(lab("play", "--checkpoint", str(run_dir), logs=logs),
                          "(the newest, model_2.zip: vecnormalize_2.json is missing)")
    # Without its manifest (a run from before manifests), loading names the missing file.
    for manifest in run_dir.glob("checkpoint_*.json"):
        manifest.unlink()
    assert_one_line_error(lab("play", "--checkpoint", str(run_dir / "model_2.zip"), logs=logs),
                          "vecnormalize_2.json is missing")


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(cut=st.integers(min_value=0))
def test_a_checkpoint_cut_short_anywhere_is_never_picked(trained, tmp_path_factory, cut):
    run_dir = trained["sb3"]
    fw = registry.get_framework("sb3")
    data = (run_dir / "model_2.zip").read_bytes()
    target = tmp_path_factory.mktemp("cut") / run_dir.name
    target.mkdir()
    for path in run_dir.iterdir():
        if path.is_file():
            (target / path.name).write_bytes(path.read_bytes())
    (target / "model_2.zip").write_bytes(data[:cut % len(data)])
    assert checkpoints.latest_complete(fw, target).iteration == 1


def test_a_legacy_checkpoint_cut_short_anywhere_is_never_picked(trained, tmp_path):
    """A run from before manifests has only its zip to judge by. SB3 stores torch's zips whole
    inside its own, so a zip cut short can still read as one: the last zip inside it."""
    run_dir = trained["sb3"]
    fw = registry.get_framework("sb3")
    data = (run_dir / "model_2.zip").read_bytes()
    target = tmp_path / run_dir.name
    target.mkdir()
    for path in run_dir.iterdir():
        if path.is_file() and not path.name.startswith(checkpoints.MANIFEST_PREFIX):
            (target / path.name).write_bytes(path.read_bytes())
    assert checkpoints.latest_complete(fw, target).iteration == 2
    picked = []
    for cut in range(0, len(data), 512):
        (target / "model_2.zip").write_bytes(data[:cut])
        if checkpoints.latest_complete(fw, target).iteration == 2:
            picked.append(cut)
    assert picked == [], f"{len(picked)} of {len(range(0, len(data), 512))} cuts picked"


def test_a_zip_of_junk_under_a_checkpoint_name_is_never_picked(trained, tmp_path):
    logs, run_dir = fresh_copy(trained["sb3"], tmp_path)
    with zipfile.ZipFile(run_dir / "model_9.zip", "w") as archive:
        archive.writestr("junk", "not a model")
    fw = registry.get_framework("sb3")
    assert checkpoints.latest_complete(fw, run_dir).iteration == 2


WEIGHTS = {"rsl_rl": "actor_state_dict", "skrl": "policy", "rl_games": "model"}


def damage_checkpoint(run_dir: Path, framework: str, damage) -> str:
    """Apply `damage` to checkpoint 2's saved dict and make its manifest match, as a hand edit
    of the file would; returns the file's name."""
    name = checkpoints_name(framework, 2)
    saved = torch.load(run_dir / name, weights_only=True)
    damage(saved)
    torch.save(saved, run_dir / name)
    remanifest(run_dir, 2)
    return name


def assert_every_reader_refuses(logs: Path, framework: str, phrase: str) -> None:
    """play, export and a resume each end in one line naming `phrase`, and write nothing."""
    before = snapshot_of(logs)
    for args in (["play", "--last"], ["export", "onnx"],
                 ["train", "--task", "cartpole", "--framework", framework, "--checkpoint",
                  "latest", "--max-iterations", "3"]):
        assert_one_line_error(lab(*args, logs=logs), phrase)
    assert snapshot_of(logs) == before


@pytest.mark.parametrize("framework", list(WEIGHTS))
def test_a_checkpoint_with_nan_weights_is_refused_before_anything_is_written(framework, trained,
                                                                              tmp_path):
    logs, run_dir = fresh_copy(trained[framework], tmp_path)
    (run_dir / "exported").mkdir()
    (run_dir / "exported" / "policy.onnx").write_text("the previous export")

    def nan_weights(saved: dict) -> None:
        for tensor in saved[WEIGHTS[framework]].values():
            if tensor.is_floating_point():
                tensor.fill_(float("nan"))

    name = damage_checkpoint(run_dir, framework, nan_weights)
    assert_every_reader_refuses(logs, framework, f"{name} holds non-finite weights")
    assert (run_dir / "exported" / "policy.onnx").read_text() == "the previous export"


# Damaged checkpoints, states and params: one line ---------------------------------------------
RSL_RL_DAMAGE = {
    "unknown activation": lambda s: s["infos"]["lab"]["actor"].update(activation="swishy"),
    "unknown keyword": lambda s: s["infos"]["lab"]["actor"].update(frobnicate=1),
    "missing class_name": lambda s: s["infos"]["lab"]["actor"].pop("class_name"),
    "huge hidden sizes": lambda s: s["infos"]["lab"]["actor"].update(
        hidden_dims=[10**7, 10**7]),
    "string size": lambda s: s["infos"]["lab"].update(observation_size="four"),
    "normalizer of the wrong size": lambda s: s["actor_state_dict"].update(
        {k: torch.zeros(7) for k in s["actor_state_dict"] if "normalizer" in k}),
}
SKRL_DAMAGE = {
    "unknown activation": lambda s: s["lab"].update(activation="swishy"),
    "huge hidden sizes": lambda s: s["lab"].update(hidden_sizes=[10**7, 10**7]),
    "string size": lambda s: s["lab"].update(hidden_sizes=["sixteen"]),
    "normalizer of the wrong size": lambda s: s["observation_preprocessor"].update(
        running_mean=torch.zeros(7), running_variance=torch.ones(7)),
    "no steps": lambda s: s["lab"].pop("steps"),
}
# rl_games' checkpoint describes no network (lab rebuilds it from the run's config): what can be
# damaged is the model state and the counters.
RL_GAMES_DAMAGE = {
    "no model": lambda s: s.pop("model"),
    "a layer of the wrong size": lambda s: s["model"].update(
        {"a2c_network.mu.weight": torch.zeros(3, 3)}),
    "normalizer of the wrong size": lambda s: s["model"].update(
        {"running_mean_std.running_mean": torch.zeros(7, dtype=torch.float64)}),
    "a list for the model": lambda s: s.update(model=[1, 2]),
}
DAMAGE = {"rsl_rl": RSL_RL_DAMAGE, "skrl": SKRL_DAMAGE, "rl_games": RL_GAMES_DAMAGE}


@pytest.mark.parametrize("framework, damage", [
    (framework, name) for framework, cases in DAMAGE.items() for name in cases])
def test_a_checkpoint_with_damaged_metadata_is_one_line(framework, damage, trained, tmp_path):
    logs, run_dir = fresh_copy(trained[framework], tmp_path)
    name = damage_checkpoint(run_dir, framework, DAMAGE[framework][damage])
    assert_every_reader_refuses(logs, framework, name)


STATE_DAMAGE = {"empty dict": {}, "a list": [1, 2], "no rng": "drop rng",
                "wrong generator types": "strings"}


@pytest.mark.parametrize("damage", list(STATE_DAMAGE))
def test_a_damaged_state_file_is_one_line_and_the_run_keeps_its_state(damage, trained,
                                                                      tmp_path):
    logs, run_dir = fresh_copy(trained["rsl_rl"], tmp_path)
    path = run_dir / "state_2.pt"
    state = torch.load(path, weights_only=True)
    if STATE_DAMAGE[damage] == "drop rng":
        state.pop("rng")
    elif STATE_DAMAGE[damage] == "strings":
        state["rng"]["torch"] = "not a generator"
        state["env"]["generator"] = [1, 2, 3]
    else:
        state = STATE_DAMAGE[damage]
    torch.save(state, path)
    remanifest(run_dir, 2)
    before = snapshot_of(logs)
    assert_one_line_error(resume(logs, "rsl_rl", 3), "state_2.pt")
    assert snapshot_of(logs) == before
    assert json.loads((run_dir / rundir.MANIFEST).read_text())["state"] == rundir.FINISHED


@pytest.mark.parametrize("how", ["invalid UTF-8", "nested 5,000 deep", "a link to /dev/zero",
                                 "a FIFO", "a billion-laughs alias bomb"])
def test_a_params_file_that_cannot_be_read_is_one_line_and_never_hangs(how, trained, tmp_path):
    logs, run_dir = fresh_copy(trained["rsl_rl"], tmp_path)
    path = run_dir / rundir.ENV_PARAMS
    path.unlink()
    if how == "invalid UTF-8":
        path.write_bytes(b"num_envs: \xff\xfe\n")
    elif how == "nested 5,000 deep":
        path.write_text("a: " + "[" * 5000 + "]" * 5000 + "\n")
    elif how == "a link to /dev/zero":
        path.symlink_to("/dev/zero")
    elif how == "a FIFO":
        os.mkfifo(path)
    else:
        lines = ["a: &a [x, x, x, x, x, x, x, x, x, x]"]
        lines += [f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join([f'*{chr(97 + i)}'] * 10)}]"
                  for i in range(8)]
        path.write_text("\n".join(lines) + "\n")
    started = time.monotonic()
    assert_one_line_error(lab("play", "--last", logs=logs), "params/env.yaml")
    assert time.monotonic() - started < 30


def test_an_alias_bomb_in_a_config_file_or_a_set_value_is_one_line(tmp_path):
    bomb = "[" + ", ".join(["&a [x, x, x, x, x, x, x, x, x, x]"] + ["*a"] * 20000) + "]"
    (tmp_path / "c.yaml").write_text(f"env:\n  kwargs:\n    k: {bomb}\n")
    for args in (["--config", str(tmp_path / "c.yaml")], ["--set", f"env.kwargs.k={bomb}"]):
        result = lab("config", "show", "--task", "gym:Pendulum-v1", "--framework", "sb3", *args,
                     logs=tmp_path)
        assert_one_line_error(result, "expands to more than")


# lab runs: one bad file hides nothing -----------------------------------------------------------
WHOLLY_BAD = [b"[]", b"null", b"42", b'{"a": "\xff"}', b"{"]
# A field of the wrong type, in the file that has it.
FIELD_BAD = [(rundir.MANIFEST, "started", 5), (rundir.MANIFEST, "first_started", "garbage"),
             (rundir.SUMMARY, "steps", "many"), (rundir.SUMMARY, "mean_return", [1, 2])]
CASES = [*((which, content) for which in (rundir.MANIFEST, rundir.SUMMARY)
           for content in WHOLLY_BAD),
         *((which, (field, value)) for which, field, value in FIELD_BAD)]


@pytest.mark.parametrize("which, damage", CASES)
def test_runs_lists_every_readable_run_and_marks_a_damaged_one(which, damage, trained,
                                                               tmp_path):
    logs = tmp_path / "logs"
    for framework in ("rsl_rl", "skrl"):
        fresh_copy(trained[framework], tmp_path)
    damaged = next(logs.glob("skrl/cartpole/*"))
    if isinstance(damage, tuple):
        field, value = damage
        data = json.loads((damaged / which).read_text())
        damage = json.dumps({**data, field: value}).encode()
    (damaged / which).write_bytes(damage)
    rows = {row.framework: row for row in rundir.table(logs)}
    assert rows["rsl_rl"].state == rundir.FINISHED
    assert rows["skrl"].state == rundir.DAMAGED and str(damaged) in rows["skrl"].problem
    for args in (["runs"], ["runs", "--json"]):
        result = lab(*args, logs=logs)
        assert result.exit_code == 0 and "Traceback" not in result.output
        assert "rsl_rl" in result.stdout and "damaged" in result.stdout


def test_a_pid_that_is_not_a_pid_or_not_this_run_is_not_running(trained, tmp_path):
    logs, run_dir = fresh_copy(trained["rsl_rl"], tmp_path)
    (run_dir / rundir.SUMMARY).unlink()
    manifest = json.loads((run_dir / rundir.MANIFEST).read_text())
    for pid, started in ((2**70, None), (1, None), (os.getpid(), 12345)):
        manifest.update(state=rundir.RUNNING, pid=pid, pid_started=started)
        (run_dir / rundir.MANIFEST).write_text(json.dumps(manifest))
        assert lab("runs", logs=logs).exit_code == 0
        assert rundir.run_state(rundir.Run(run_dir)) == rundir.FAILED


# Garbage in every file lab reads from a run dir -------------------------------------------------
FILES = [rundir.MANIFEST, rundir.SUMMARY, rundir.ENV_PARAMS, rundir.AGENT_PARAMS, "state_2.pt",
         "model_2"]


@settings(max_examples=30, deadline=None, suppress_health_check=list(HealthCheck))
@given(which=st.sampled_from(FILES), framework=st.sampled_from(FRAMEWORKS),
       garbage=st.one_of(st.binary(max_size=300),
                         st.recursive(st.none() | st.booleans() | st.integers() | st.floats()
                                      | st.text(max_size=20),
                                      lambda inner: st.lists(inner, max_size=4)
                                      | st.dictionaries(st.text(max_size=8), inner, max_size=4),
                                      max_leaves=12).map(lambda v: json.dumps(v).encode())))
def test_garbage_in_any_run_file_is_one_line_writes_nothing_and_hides_no_run(
        which, framework, garbage, trained, tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("garbage")
    logs, run_dir = fresh_copy(trained[framework], tmp_path)
    other_logs, other = fresh_copy(trained["rsl_rl" if framework != "rsl_rl" else "skrl"],
                                   tmp_path)
    name = which if which != "model_2" else checkpoints_name(framework, 2)
    (run_dir / name).write_bytes(garbage)
    if name.startswith(("state_", "model_")):
        remanifest(run_dir, 2)  # as if it had been written so: lab must still not trip on it
    before = snapshot_of(logs)
    commands = {  # the commands that read the file
        "play": ["play", "--run", str(run_dir), "--episodes", "1"],
        "export": ["export", "onnx", "--run", str(run_dir)],
        "train": ["train", "--task", "cartpole", "--framework", framework, "--checkpoint",
                  str(run_dir), "--max-iterations", "3"]}
    reading = {"state_2.pt": ["train"], "model_2": ["play", "export"]}.get(which,
                                                                            ["play", "train"])
    for args in (commands[name] for name in reading):
        result = lab(*args, logs=logs)
        assert "Traceback" not in result.output and result.exception is None or \
            isinstance(result.exception, SystemExit), result.output
        if result.exit_code != 0:  # some garbage is still valid data (a summary of {}): fine
            assert_one_line_error(result)
            assert snapshot_of(logs) == before
        before = snapshot_of(logs)
    listed = {row.dir for row in rundir.table(logs)}
    assert run_dir in listed and other in listed


# A full disk ----------------------------------------------------------------------------------
@pytest.fixture
def tiny_disk(tmp_path) -> Path:
    """A 2 MiB file system (tmpfs), for training until the disk is full; skipped where no file
    system can be mounted."""
    path = tmp_path / "tiny"
    path.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(path)],
                             capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a small file system here: {mounted.stderr.decode().strip()}")
    yield path
    subprocess.run(["umount", "--lazy", str(path)], check=True)


@pytest.mark.parametrize("framework", FRAMEWORKS)
def test_a_full_disk_ends_the_run_in_one_line_and_keeps_the_last_checkpoint(framework,
                                                                            tiny_disk):
    result = lab("train", "--task", "cartpole", "--framework", framework, "--num-envs", "8",
                 "--max-iterations", "500", "--set", "agent.save_interval=1", logs=tiny_disk)
    assert_one_line_error(result, "No space left on device", mid_run=True)
    (run_dir,) = tiny_disk.glob(f"{framework}/cartpole/*")
    assert not list(tiny_disk.rglob(".tmp*"))
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == rundir.FAILED and "No space left" in summary["error"]
    fw = registry.get_framework(framework)
    last = checkpoints.latest_complete(fw, run_dir)
    assert last is not None and summary["checkpoint"] == last.path.name
    assert_one_line_error(resume(tiny_disk, framework, 500), "No space left on device",
                          mid_run=True)
    subprocess.run(["mount", "-o", "remount,size=64m", str(tiny_disk)], check=True)
    assert resume(tiny_disk, framework, last.iteration + 2).exit_code == 0


# Exports, deleted run dirs, durable writes ------------------------------------------------------
KILLED_MID_EXPORT = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from labcli.runs import export

    def slow(policy, example, path, *metadata):
        Path(path).write_bytes(b"half an export")
        print("writing", flush=True)
        time.sleep(60)

    export._export_onnx = slow
    export.export("onnx", run_dir=Path(sys.argv[1]))
""")


def test_a_kill_during_a_re_export_leaves_the_previous_export(trained, tmp_path):
    logs, run_dir = fresh_copy(trained["rsl_rl"], tmp_path)
    assert lab("export", "onnx", "--run", str(run_dir), logs=logs).exit_code == 0
    exported = {p.name: p.read_bytes() for p in (run_dir / "exported").iterdir()}
    kill_when_writing(KILLED_MID_EXPORT, str(run_dir))
    for name, data in exported.items():
        assert (run_dir / "exported" / name).read_bytes() == data
    # The killed export's half-written file stays until the next export, which removes it.
    (stale,) = (run_dir / "exported").glob(".tmp_policy*")
    assert lab("export", "onnx", "--run", str(run_dir), logs=logs).exit_code == 0
    assert not stale.exists()
    assert sorted(p.name for p in (run_dir / "exported").iterdir()) == sorted(exported)


LONG_TRAIN = ["--num-envs", "4", "--max-iterations", "100000"]
# Short iterations, a checkpoint after each.
SHORT = {"rsl_rl": ["agent.num_steps_per_env=8", "agent.num_learning_epochs=1"],
         "sb3": ["agent.n_steps=8", "agent.batch_size=16", "agent.n_epochs=1"],
         "skrl": ["agent.rollouts=8", "agent.learning_epochs=1"]}


def start_training(logs: Path, *extra: str, framework: str = "rsl_rl") -> subprocess.Popen:
    short = [arg for setting in SHORT[framework] for arg in ("--set", setting)]
    return subprocess.Popen(
        [sys.executable, "-m", "labcli", "train", "--task", "cartpole", "--framework", framework,
         *LONG_TRAIN, *short, *extra], env={**os.environ, "LAB_LOGS_DIR": str(logs)},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for_running(logs: Path, timeout: float = 120, done: str = ".candidate",
                     framework: str = "rsl_rl") -> Path:
    """The run dir, once `done` is in it (the first iteration's last good state by default)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for run_dir in logs.glob(f"{framework}/cartpole/*"):
            if (run_dir / done).exists() or (run_dir / ".good").exists():
                return run_dir
        time.sleep(0.05)
    raise AssertionError(f"the run did not write {done}")


def test_a_run_dir_deleted_while_its_checkpoints_are_listed_holds_none(tmp_path, monkeypatch):
    """The race the deleted-run test met 1 time in 2 fresh-clone runs: the run dir existed when
    glob checked it and was gone when it listed it (the summary lists checkpoints)."""
    from labcli.plugins import registry

    spec = registry.get_framework("rsl_rl")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "model_1.pt").write_bytes(b"")
    listing = os.scandir

    def deleted_first(path):
        if isinstance(path, (str, os.PathLike)) and Path(path) == run_dir:  # not rmtree's fds
            shutil.rmtree(run_dir)
        return listing(path)

    monkeypatch.setattr(os, "scandir", deleted_first)
    assert spec.checkpoints(run_dir) == []


@pytest.mark.parametrize("framework", ["rsl_rl", "sb3", "skrl"])
def test_a_run_dir_deleted_while_training_ends_it_in_one_line_and_stays_deleted(tmp_path,
                                                                                framework):
    logs = tmp_path / "logs"
    proc = start_training(logs, "--set", "agent.save_interval=1", framework=framework)
    try:
        run_dir = wait_for_running(logs, framework=framework)
        # The run keeps writing while rm walks the tree, so one pass can find a directory
        # refilled behind it; a user would repeat the rm, and so does the test.
        for _ in range(20):
            if subprocess.run(["rm", "-rf", str(run_dir)], capture_output=True).returncode == 0:
                break
        else:
            pytest.fail(f"rm -rf {run_dir} kept failing")
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 2, err
    assert err.strip().splitlines()[-1].startswith("error: ") and "Traceback" not in err
    assert "no longer exists" in err and not run_dir.exists()


def test_a_run_dir_deleted_before_sb3_logs_its_figures_is_said_as_a_deleted_run(tmp_path,
                                                                             monkeypatch):
    """The race the deleted-run test met with sb3: SB3's own TensorBoard writer, not lab's
    checkpoint, was the first to find the run dir gone (its thread's error, re-raised by the
    writer's next call)."""
    from stable_baselines3.common.logger import TensorBoardOutputFormat

    write = TensorBoardOutputFormat.write

    def deleted_first(self, *args, **kwargs):
        shutil.rmtree(Path(self.writer.log_dir))
        write(self, *args, **kwargs)
        self.writer.flush()  # waits for the writer's thread and raises what it met

    monkeypatch.setattr(TensorBoardOutputFormat, "write", deleted_first)
    with pytest.raises(LabError, match="no longer exists: it was deleted or moved"):
        testing.train_small("sb3", tmp_path, 3, testing.SMALL_AGENTS["sb3"])


@pytest.mark.parametrize("when", ["after the model", "before the model", "while checked"])
def test_a_checkpoint_deleted_while_it_is_written_is_said_as_a_deleted_run(tmp_path, when):
    # The races the test above can hit: rm has emptied the staging directory, not yet the run
    # dir, when lab looks for the model it was handed, when the library writes it, or when
    # lab reads it back to check it (sb3's reader: "not a loadable SB3 model").
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    fw = registry.get_framework("rsl_rl")

    def save(path):
        if when != "before the model":
            path.write_bytes(b"model")
        if when != "while checked":
            shutil.rmtree(path.parent)
        if when == "before the model":
            path.write_bytes(b"model")  # FileNotFoundError, as torch.save's own

    def check(path):
        shutil.rmtree(path.parent)
        raise LabError(f"checkpoint {path} is not a loadable model: cannot be opened")

    with pytest.raises(LabError, match="no longer exists: it was deleted or moved"):
        checkpoints.write(run_dir, fw, 1, save, check=check if when == "while checked" else None)
    assert list(run_dir.iterdir()) == []


def test_a_checkpoint_emptied_while_it_is_published_is_said_as_a_deleted_run(tmp_path,
                                                                          monkeypatch):
    """The race of the test above at its end: rm empties the staging directory after lab
    listed its files, which it then finds gone."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    fsync = files.fsync_file

    def fsync_then_rm_the_others(path):
        fsync(path)
        for other in path.parent.iterdir():
            if other != path:
                other.unlink()

    monkeypatch.setattr(files, "fsync_file", fsync_then_rm_the_others)
    with pytest.raises(LabError, match="no longer exists: it was deleted or moved"):
        checkpoints.write(run_dir, registry.get_framework("rsl_rl"), 1,
                          lambda path: path.write_bytes(b"model"),
                          lambda staging: (staging / "env_state").write_bytes(b"state"))


@pytest.mark.parametrize("framework", ["rsl_rl", "sb3", "skrl"])
def test_a_run_dir_deleted_just_before_the_library_saves_stays_deleted(
        tmp_path, monkeypatch, framework):
    """The race the test above can hit between the staging directory and the library's save:
    given a path, SB3 created the directories missing above it, the run dir among them."""
    write = checkpoints.write

    def deleted_first(directory, fw, iteration, save, *args, **kwargs):
        def save_after_rm(path):
            if iteration == 2:  # the run dir (`directory` may be a candidate inside it)
                shutil.rmtree(kwargs.get("below") or directory)
            save(path)

        return write(directory, fw, iteration, save_after_rm, *args, **kwargs)

    monkeypatch.setattr(checkpoints, "write", deleted_first)
    with pytest.raises(LabError, match="no longer exists: it was deleted or moved"):
        testing.train_small(framework, tmp_path, 3, [*SHORT[framework], "agent.save_interval=1"])
    assert list(tmp_path.glob(f"{framework}/cartpole/*")) == []


def test_a_file_written_into_a_directory_deleted_under_lab_says_it_was_deleted(
        tmp_path, monkeypatch):
    # The third race of the first test above: the checkpoint's files were published into
    # .candidate, which rm then removed before lab wrote the manifest beside them.
    run_dir = tmp_path / "run"
    candidate = run_dir / ".candidate"
    candidate.mkdir(parents=True)
    real_dir = files.real_dir

    def checked_then_deleted(path, create=True, below=None):
        checked = real_dir(path, create, below)
        shutil.rmtree(candidate, ignore_errors=True)
        return checked

    monkeypatch.setattr(files, "real_dir", checked_then_deleted)
    with pytest.raises(LabError, match=r"\.candidate no longer exists: it was deleted"):
        files.write_atomic(candidate / "checkpoint_2.json", "{}", below=run_dir)
    assert list(run_dir.iterdir()) == []


def test_a_second_writer_is_refused_at_once_naming_the_first(tmp_path):
    logs = tmp_path / "logs"
    proc = start_training(logs, "--set", "agent.save_interval=1")
    try:
        run_dir = wait_for_running(logs, done="checkpoint_1.json")  # something to resume from
        before = snapshot_of(run_dir / "params")
        result = lab("train", "--task", "cartpole", "--framework", "rsl_rl", "--checkpoint",
                     str(run_dir), "--max-iterations", "100001", logs=logs)
        assert_one_line_error(result, "is being written by process", str(proc.pid))
        assert snapshot_of(run_dir / "params") == before
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=60)
    assert proc.returncode == 130


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="names fds through /proc")
def test_checkpoints_and_run_files_are_fsynced(tmp_path, monkeypatch):
    """Renamed into place is atomic; fsynced (the file, then its directory) is durable."""
    synced: list[str] = []
    original = os.fsync

    def fsync(fd: int) -> None:
        synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        original(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    outcome = testing.train_small("rsl_rl", tmp_path, 2, testing.SMALL_AGENTS["rsl_rl"])
    run_dir = str(outcome.run.dir)
    assert run_dir in synced  # the directory, after each rename into it
    for staged in ("/model_2.pt", "/state_2.pt"):  # in the checkpoint's staging dir
        assert any(p.endswith(staged) and "/.tmp_checkpoint_2." in p for p in synced)
    assert any(Path(p).name.startswith(".tmp_summary.") for p in synced)


# Signals while saving ---------------------------------------------------------------------------
SLOW_SAVE = textwrap.dedent("""
    import io, sys, time
    from pathlib import Path
    from rich.console import Console
    from labcli.runs import checkpoints, training

    original = checkpoints.write
    def slow(directory, *args, **kwargs):
        if Path(directory).name != ".candidate":
            print("saving", flush=True)
            time.sleep(1.5)
        return original(directory, *args, **kwargs)
    checkpoints.write = slow
    outcome = training.train("cartpole", "rsl_rl", num_envs=4, max_iterations=100000,
                             logs_dir=Path(sys.argv[1]), overrides=["agent.num_steps_per_env=8",
                             "agent.save_interval=3"], console=Console(file=sys.stderr))
    sys.exit(128 + outcome.summary.get("signal", 0) if outcome.summary["state"] == "interrupted"
             else 0)
""")


def test_a_second_ctrl_c_while_saving_is_acknowledged_and_changes_nothing(tmp_path):
    logs = tmp_path / "logs"
    proc = subprocess.Popen([sys.executable, "-c", SLOW_SAVE, str(logs)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "saving"
        proc.send_signal(signal.SIGINT)
        time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "SIGINT again" in err and "Traceback" not in err
    (run_dir,) = logs.glob("rsl_rl/cartpole/*")
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    fw = registry.get_framework("rsl_rl")
    assert summary["state"] == rundir.INTERRUPTED
    assert checkpoints.complete(fw, checkpoints.Checkpoint(
        fw.checkpoint_path(run_dir, summary["iterations"]), summary["iterations"]))


# Numbers out of range ---------------------------------------------------------------------------
@pytest.mark.parametrize("framework, setting, key", [
    ("sb3", "agent.net_arch=[10000000000]", "agent.net_arch"),
    ("sb3", "agent.net_arch=[-5]", "agent.net_arch"),
    ("sb3", "agent.n_steps=1000000000", "agent.n_steps"),
    ("sb3", "agent.max_grad_norm=-1", "agent.max_grad_norm"),
    ("sb3", "agent.target_kl=-0.1", "agent.target_kl"),
    ("rsl_rl", "agent.actor_hidden_dims=[10000000000]", "agent.actor_hidden_dims"),
    ("rsl_rl", "agent.num_steps_per_env=1000000000", "agent.num_steps_per_env"),
    ("rsl_rl", "agent.num_mini_batches=100000", "agent.num_mini_batches"),
    ("skrl", "agent.rollouts=1000000000", "agent.rollouts"),
    ("skrl", "agent.mini_batches=100000", "agent.mini_batches"),
])
def test_sizes_that_cannot_work_are_one_line_naming_the_key(framework, setting, key, tmp_path):
    result = lab("train", "--task", "cartpole", "--framework", framework, "--num-envs", "4",
                 "--set", setting, logs=tmp_path)
    assert_one_line_error(result, key)
    assert not list(tmp_path.rglob("run.json"))


def test_a_seed_out_of_range_is_one_line(tmp_path):
    for args in (["play", "--agent", "random", "--task", "cartpole", "--seed", str(2**70)],
                 ["train", "--task", "cartpole", "--framework", "sb3", "--seed", str(2**70)]):
        assert_one_line_error(lab(*args, logs=tmp_path), "seed")


def test_tensorboard_s_writer_thread_failing_on_a_vanished_dir_prints_no_traceback(
        monkeypatch):
    """Its error reaches lab through the writer's next call, which lab says in one line; the
    thread's own print would be a traceback beside it. Any other thread's error still goes to
    the hook that prints it."""
    from tensorboard.summary.writer.event_file_writer import _AsyncWriterThread

    from labcli.runs.session import _writer_thread_quiet

    printed: list[type] = []
    monkeypatch.setattr(threading, "excepthook", lambda args: printed.append(args.exc_type))

    def failing(thread: threading.Thread, error: Exception) -> threading.Thread:
        def run():
            raise error
        thread.run = run
        return thread

    with _writer_thread_quiet():
        writer_thread = _AsyncWriterThread.__new__(_AsyncWriterThread)
        threading.Thread.__init__(writer_thread)
        for thread in (failing(writer_thread, FileNotFoundError(2, "No such file")),
                       failing(threading.Thread(), ValueError("a bug"))):
            thread.start()
            thread.join()
    assert printed == [ValueError]
