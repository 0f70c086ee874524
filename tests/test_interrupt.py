"""Interruption: SIGINT/SIGTERM at any point of `lab train` (real processes, real signals), a
signal during a framework's update, SIGKILL while a checkpoint is written, and `latest` never
picking an incomplete checkpoint."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import torch
from lab_skrl.framework import SkrlFramework
from runfiles import kill_when_writing

from labcli import testing
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.plugins.hookspecs import hookimpl
from labcli.runs import checkpoints, rundir

SB3_SMALL = ["--set", "agent.n_steps=8", "--set", "agent.batch_size=16", "--set",
             "agent.n_epochs=1", "--set", "agent.net_arch=[16]"]
# Iterations take milliseconds at this size: far more than a test waits for.
ENDLESS = ["--num-envs", "4", "--max-iterations", "1000000", "--set", "agent.save_interval=1"]
STOP_WITHIN_S = 10.0


def start(logs: Path, *args: str) -> subprocess.Popen:
    """`lab train` as a user starts it: its own process, the console script's entry point."""
    return subprocess.Popen(
        [sys.executable, "-m", "labcli", "train", "--task", "cartpole", "--framework", "sb3",
         *SB3_SMALL, *args], env={**os.environ, "LAB_LOGS_DIR": str(logs)},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for(condition, timeout: float = 60.0, interval: float = 0.05) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out waiting"
        time.sleep(interval)


def run_dirs(logs: Path) -> list[Path]:
    return sorted(p.parent for p in logs.glob(f"sb3/cartpole/*/{rundir.MANIFEST}"))


def newest_iteration(run_dir: Path) -> int:
    found = registry.get_framework("sb3").checkpoints(run_dir)
    return found[-1].iteration if found else 0


def stop(proc: subprocess.Popen, signum: int) -> tuple[int, str, float]:
    t0 = time.monotonic()
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    return proc.returncode, err, time.monotonic() - t0


def assert_interrupted_with_a_loadable_checkpoint(run_dir: Path) -> dict:
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == rundir.INTERRUPTED
    assert json.loads((run_dir / rundir.MANIFEST).read_text())["state"] == rundir.INTERRUPTED
    assert rundir.run_state(rundir.Run(run_dir)) == rundir.INTERRUPTED
    fw = registry.get_framework("sb3")
    checkpoint = fw.checkpoint_path(run_dir, summary["iterations"])
    assert summary["checkpoint"] == checkpoint.name and checkpoint.is_file()
    assert checkpoints.latest_complete(fw, run_dir).path == checkpoint
    assert summary["steps"] == summary["iterations"] * 4 * 8  # 4 envs x 8 steps
    env = testing.make_env()
    try:
        testing.load_policy("sb3", checkpoint, env)
    finally:
        env.close()
    assert not list(run_dir.glob(".tmp_*"))
    return summary


def test_sigint_and_sigterm_mid_training_of_two_concurrent_runs(tmp_path):
    """Two runs started together get their own dirs and show as running with their pids; each
    stops within seconds of its signal with a checkpoint, a summary and 128 + the signal."""
    logs = tmp_path / "logs"
    procs = [start(logs, *ENDLESS, "--run-name", "same") for _ in range(2)]
    try:
        wait_for(lambda: len(run_dirs(logs)) == 2
                 and all(newest_iteration(d) >= 2 for d in run_dirs(logs)))
        by_pid = {json.loads((d / rundir.MANIFEST).read_text())["pid"]: d for d in run_dirs(logs)}
        assert set(by_pid) == {p.pid for p in procs}  # distinct dirs, one per process
        for d in by_pid.values():
            assert rundir.run_state(rundir.Run(d)) == rundir.RUNNING
        results = [stop(proc, signum) for proc, signum in zip(
            procs, (signal.SIGINT, signal.SIGTERM), strict=True)]
    finally:
        for proc in procs:
            proc.kill()
    for proc, (code, err, took), expected in zip(procs, results, (130, 143), strict=True):
        assert code == expected, err
        assert took < STOP_WITHIN_S and "Traceback" not in err
        summary = assert_interrupted_with_a_loadable_checkpoint(by_pid[proc.pid])
        assert summary["iterations"] >= 2


def test_a_signal_during_start_up_leaves_a_consistent_run(tmp_path):
    """Once the run dir exists (the env and the agent are still being built), a signal still
    ends with a loadable checkpoint (of iteration 0) and an 'interrupted' summary."""
    logs = tmp_path / "logs"
    proc = start(logs, *ENDLESS)
    try:
        # The run dir itself, polled every 2 ms: its manifest is written later, and iterations
        # take milliseconds once training runs, so a slower poll would often signal a run that
        # had left start-up (seen: 2 iterations done, 1 in 20 runs).
        wait_for(lambda: any(logs.glob("sb3/cartpole/*")), interval=0.002)
        code, err, took = stop(proc, signal.SIGINT)
    finally:
        proc.kill()
    assert code == 130 and took < STOP_WITHIN_S and "Traceback" not in err, err
    summary = assert_interrupted_with_a_loadable_checkpoint(run_dirs(logs)[0])
    assert summary["iterations"] <= 1


def test_a_signal_while_lab_imports_is_one_line_and_writes_nothing(tmp_path):
    logs = tmp_path / "logs"
    proc = start(logs, *ENDLESS)
    try:
        time.sleep(0.5)  # torch and the learning libraries take seconds to import
        assert not logs.exists()
        code, err, _ = stop(proc, signal.SIGTERM)
    finally:
        proc.kill()
    assert code == 143, err
    # What lab train announced before importing them, if it got that far, then one line.
    *announced, last = err.splitlines()
    assert all(line.startswith("train ") for line in announced) and len(announced) <= 1, err
    assert "SIGTERM" in last and "nothing was written" in last
    assert not logs.exists()


# A stop asked during the update: the update finishes, that iteration is checkpointed, no other
# starts. Each library's update function, by module and name.
UPDATES = {
    "sb3": ("stable_baselines3.ppo.ppo", "PPO", "train"),
    "rsl_rl": ("rsl_rl.algorithms.ppo", "PPO", "update"),
    "skrl": ("skrl.agents.torch.ppo.ppo", "PPO", "update"),
    "rl_games": ("rl_games.common.a2c_common", "ContinuousA2CBase", "prepare_dataset"),
}
SMALL = testing.SMALL_AGENTS


@pytest.mark.parametrize("name", list(UPDATES))
def test_sigint_during_the_update_checkpoints_that_iteration(name, tmp_path, monkeypatch):
    module, cls, method = UPDATES[name]
    owner = getattr(__import__(module, fromlist=[cls]), cls)
    original = getattr(owner, method)
    updates = 0

    def update(self, *args, **kwargs):
        nonlocal updates
        updates += 1
        if updates == 2:
            os.kill(os.getpid(), signal.SIGINT)  # arrives inside the library's update
        return original(self, *args, **kwargs)

    monkeypatch.setattr(owner, method, update)
    outcome = testing.train_small(name, tmp_path, 50, SMALL[name])
    assert updates == 2
    assert outcome.summary["state"] == rundir.INTERRUPTED and outcome.summary["iterations"] == 2
    assert outcome.summary["signal"] == signal.SIGINT
    fw = registry.get_framework(name)
    assert [c.iteration for c in fw.checkpoints(outcome.run.dir)] == [2]
    resumed = testing.train_small(name, tmp_path, 3, SMALL[name], checkpoint=checkpoints.LATEST)
    assert resumed.run.dir == outcome.run.dir and resumed.summary["state"] == rundir.FINISHED


class _NoTrainingContext(SkrlFramework):
    """skrl whose train leaves `ctx.training` out: StopTraining escapes it."""

    def train(self, env, ctx):
        ctx.training = lambda save: contextlib.nullcontext()
        super().train(env, ctx)


def test_a_stop_that_escapes_a_plugin_s_train_ends_the_run_keeping_its_checkpoints(
        register_plugin, tmp_path):
    skrl = registry.get_framework("skrl")
    adapter = dataclasses.replace(skrl.adapter, name="careless.adapter", framework="careless")

    class Plugin:
        @hookimpl
        def register_frameworks(self, register):
            register(dataclasses.replace(skrl, name="careless", framework=_NoTrainingContext,
                                         wrappers=(adapter,)))

    register_plugin(Plugin(), "careless")
    steps_per_iteration = 8  # agent.rollouts
    with testing.sigint_at_env_step(3 * steps_per_iteration + 4):  # mid-way through the 4th
        outcome = testing.train_small("careless", tmp_path, 10,
                                      [*SMALL["skrl"], "agent.save_interval=2"])
    assert outcome.summary["state"] == rundir.INTERRUPTED
    # Iteration 3, not due, goes unsaved without ctx.training; iteration 2's checkpoint stands.
    assert outcome.summary["checkpoint"] == "model_2.pt"
    assert [c.iteration for c in registry.get_framework("careless").checkpoints(
        outcome.run.dir)] == [2]


# SIGKILL mid-write: the child writes its next checkpoint slowly, and is killed half-way.
KILLED_MID_SAVE = textwrap.dedent("""
    import io, sys, time
    from pathlib import Path
    from rich.console import Console
    from lab_sb3.framework import PPO
    from labcli.runs import training

    original = PPO.save
    def slow_save(self, file, *args, **kwargs):
        path = Path(file.name)  # the checkpoint's staging dir in the run dir (not the candidate's)
        if path.name == "model_2.zip" and path.parent.parent.name != ".candidate":
            file.write(b"PK half a checkpoint")
            file.flush()
            print("writing", flush=True)
            time.sleep(60)
        return original(self, file, *args, **kwargs)
    PPO.save = slow_save
    training.train("cartpole", "sb3", num_envs=4, max_iterations=5, logs_dir=Path(sys.argv[1]),
                   overrides=["agent.n_steps=8", "agent.batch_size=16", "agent.n_epochs=1",
                              "agent.save_interval=1"], console=Console(file=io.StringIO()))
""")


def test_sigkill_while_a_checkpoint_is_written_leaves_the_previous_one(tmp_path):
    logs = tmp_path / "logs"
    kill_when_writing(KILLED_MID_SAVE, str(logs))
    (run_dir,) = run_dirs(logs)
    fw = registry.get_framework("sb3")
    assert not fw.checkpoint_path(run_dir, 2).exists()  # only its staging dir was written
    assert list(run_dir.glob(".tmp_checkpoint_2.*/model_2.zip"))
    run, found = checkpoints.find(checkpoints.LATEST, logs, "cartpole", fw)
    assert run.dir == run_dir and found.iteration == 1
    assert rundir.run_state(run) == rundir.FAILED  # recorded as running, its process is gone
    resumed = testing.train_small("sb3", logs, 2, ["agent.n_steps=8", "agent.batch_size=16",
                                                   "agent.n_epochs=1"],
                                  checkpoint=checkpoints.LATEST)
    assert resumed.summary["state"] == rundir.FINISHED and resumed.summary["iterations"] == 2
    assert not list(run_dir.glob(".tmp_*"))  # the killed run's staging dir is gone


def test_latest_passes_over_stray_and_truncated_checkpoints(tmp_path):
    fw = registry.get_framework("rsl_rl")
    outcome = testing.train_small("rsl_rl", tmp_path, 2, [*SMALL["rsl_rl"],
                                                         "agent.save_interval=1"])
    run_dir = outcome.run.dir
    complete = fw.checkpoint_path(run_dir, 2)
    data = complete.read_bytes()
    fw.checkpoint_path(run_dir, 3).write_bytes(data[: len(data) // 2])  # truncated
    (run_dir / ".tmp_model_4.pt").write_bytes(data)  # a write that never got renamed
    for value in (checkpoints.LATEST, str(run_dir)):
        _, found = checkpoints.find(value, tmp_path, "cartpole", fw)
        assert found.path == complete
    with pytest.raises(LabError) as err:
        checkpoints.find(str(fw.checkpoint_path(run_dir, 3)), tmp_path, "cartpole", fw)
    assert "model_3.pt" in str(err.value) and "incomplete" in str(err.value)
    resumed = testing.train_small("rsl_rl", tmp_path, 3, SMALL["rsl_rl"],
                                  checkpoint=checkpoints.LATEST)
    assert resumed.summary["state"] == rundir.FINISHED
    assert torch.load(fw.checkpoint_path(run_dir, 3), weights_only=True)["iter"] == 3


# A worker that cannot finish its step (SIGSTOP): Ctrl-C waits a stated time, then ends the run.
STOPPED_WORKER = textwrap.dedent("""
    import io, sys
    from pathlib import Path
    from rich.console import Console
    from labcli.envs import shards
    from labcli.errors import LabError
    from labcli.runs import training

    shards.STOP_GRACE_S = 1.0
    try:
        training.train("cartpole", "rsl_rl", num_envs=256, max_iterations=100000,
                       logs_dir=Path(sys.argv[1]), console=Console(file=io.StringIO()),
                       overrides=["agent.num_steps_per_env=8", "agent.save_interval=1"])
    except LabError as exc:
        print(exc, flush=True)
""")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds workers through /proc")
def test_ctrl_c_with_a_stopped_shard_worker_ends_the_run_in_a_stated_time(tmp_path):
    """Ctrl-C stops a run at its next env step, and that step waited forever on a worker that
    was stopped (SIGSTOP): it gives up STOP_GRACE_S after the stop was asked."""
    logs = tmp_path / "logs"
    proc = subprocess.Popen([sys.executable, "-c", STOPPED_WORKER, str(logs)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not list(logs.glob("rsl_rl/cartpole/*/model_1.pt")):
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
            time.sleep(0.1)
        (worker,) = [int(pid) for pid in subprocess.run(
            ["pgrep", "-P", str(proc.pid)], capture_output=True, text=True).stdout.split()
            if b"pipe_handle" in Path(f"/proc/{pid}/cmdline").read_bytes()]
        os.kill(worker, signal.SIGSTOP)
        time.sleep(0.5)
        start = time.monotonic()
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert time.monotonic() - start < 10
    assert out.strip().splitlines()[-1].startswith(
        "the env's shards did not answer 1 s after the stop was asked: worker of "
        f"shard 1 (pid {worker}) is stopped (SIGSTOP)"), out
    assert not Path(f"/proc/{worker}").exists()
    (run_dir,) = {p.parent for p in logs.glob("rsl_rl/cartpole/*/model_1.pt")}
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == rundir.FAILED and "is stopped (SIGSTOP)" in summary["error"]


def test_sigterm_to_the_whole_process_group_stops_a_sharded_run_in_order(tmp_path):
    """`timeout` and Slurm's scancel signal every process of the job, the env's shard workers
    too (as a terminal's Ctrl-C does): they leave the stop to `lab`, which checkpoints and
    closes them."""
    logs = tmp_path / "logs"
    proc = subprocess.Popen(
        [sys.executable, "-m", "labcli", "train", "--task", "cartpole", "--framework", "rsl_rl",
         "--num-envs", "256", "--max-iterations", "100000", "--set", "agent.save_interval=1",
         "--set", "agent.num_steps_per_env=8"], env={**os.environ, "LAB_LOGS_DIR": str(logs)},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        wait_for(lambda: list(logs.glob("rsl_rl/cartpole/*/model_2.pt")), timeout=120)
        os.killpg(proc.pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 143, err
    (run_dir,) = {p.parent for p in logs.glob("rsl_rl/cartpole/*/model_2.pt")}
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == rundir.INTERRUPTED, summary
    assert summary["checkpoint"] == f"model_{summary['iterations']}.pt"
