"""Data-parallel training on this CPU: two ranks over gloo, started as torchrun starts them (their
own processes, torchrun's variables), with RSL-RL and skrl. The ranks' agents stay identical
(parameters, normalizers, optimizer state), the batch is both ranks' envs, rank 0 alone writes,
a stop reaches every rank's checkpoint and resumes, and a killed rank fails the run at once."""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import torch
import torch.multiprocessing as mp
from rich.console import Console

from labcli.envs.cores import cores
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.plugins.policy import read_torch_file
from labcli.runs import launcher, rundir, snapshot
from labcli.runs.launcher import Launch, rank_argv
from labcli.runs.ranks import SINGLE, Ranks, from_environment

ITERATIONS, ENVS = 3, 16
SMALL = {
    "rsl_rl": ["agent.num_steps_per_env=8", "agent.num_learning_epochs=2",
               "agent.num_mini_batches=2", "agent.save_interval=1"],
    "skrl": ["agent.rollouts=8", "agent.learning_epochs=2", "agent.mini_batches=2",
             "agent.save_interval=1"],
}
STEPS_PER_ENV = 8


# torchrun's variables -------------------------------------------------------------------------
def test_ranks_come_from_torchruns_variables():
    assert from_environment({}) == SINGLE
    assert from_environment({"RANK": "1", "LOCAL_RANK": "1", "WORLD_SIZE": "2"}) == Ranks(
        1, 1, 2, 2)
    ranks = from_environment({"RANK": "3", "LOCAL_RANK": "1", "WORLD_SIZE": "4",
                              "LOCAL_WORLD_SIZE": "2"})
    assert not ranks.writer and ranks.active and ranks.local_world_size == 2
    for bad in ({"RANK": "2", "LOCAL_RANK": "0", "WORLD_SIZE": "2"},
                {"RANK": "x", "LOCAL_RANK": "0", "WORLD_SIZE": "2"},
                {"RANK": "0", "LOCAL_RANK": "0", "WORLD_SIZE": "2", "LOCAL_WORLD_SIZE": "3"}):
        with pytest.raises(LabError):
            from_environment(bad)


def test_the_ranks_run_the_command_without_the_launchers_options():
    argv = ["train", "--task", "cartpole", "--nproc", "2", "--nnodes=1", "--rdzv-id", "x",
            "--rdzv-endpoint=h:1", "--num-envs", "8"]
    assert rank_argv(argv) == ["train", "--task", "cartpole", "--num-envs", "8"]
    assert Launch(2).check() == 2
    assert Launch(2, "1:3", "localhost:29400", "run").check() == 6
    assert Launch(2, "1", "127.0.0.1:29400").check() == 2  # one host, its own endpoint
    for bad in (Launch(0), Launch(2, "2"), Launch(2, "x"), Launch(2, "3:1", "h:1", "id"),
                Launch(2, "1", "x"), Launch(2, "1", "localhost:99999"), Launch(2, "1", ":29400"),
                Launch(2, "1", "localhost:"), Launch(2, "2", "no-such-host.invalid:29400", "id"),
                Launch(1, "1", None, "id")):  # --rdzv-id without several hosts
        with pytest.raises(LabError):
            bad.check()


def test_more_ranks_than_cores_is_one_line(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "labcli", "train", "--task", "cartpole", "--framework", "rsl_rl",
         "--backend", "cpu", "--nproc", str(cores() + 1)], capture_output=True, text=True,
        env={**os.environ, "LAB_LOGS_DIR": str(tmp_path)})
    assert result.returncode == 2
    assert result.stderr.strip().splitlines()[-1].startswith(
        f"error: --nproc {cores() + 1} on a host with {cores()} core(s)"), result.stderr
    assert not any(tmp_path.iterdir())


def test_a_rendezvous_that_never_answers_gives_up_in_one_line(monkeypatch):
    """A port another program holds, which accepts and never answers: torchrun's own client
    waits there forever."""
    monkeypatch.setattr(launcher, "STORE_TIMEOUT_S", 2)
    monkeypatch.setattr(launcher, "ANSWER_TIMEOUT_S", 1)
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        endpoint = f"127.0.0.1:{silent.getsockname()[1]}"
        start = time.monotonic()
        with pytest.raises(LabError, match=f"no rendezvous store answered at {endpoint} "
                                           "within 3 s"):
            launcher.launch(Launch(2, "2", endpoint, "run"), ["train"], Console())
        assert time.monotonic() - start < 20
        # torch's client waits on its connection for good: closed here, so that the abandoned
        # thread ends within this test (whose output its error goes to), not at some later one.
        (thread,) = [t for t in threading.enumerate() if t.name == "lab-rendezvous"]
        silent.settimeout(0.1)
        deadline = time.monotonic() + 30
        while thread.is_alive() and time.monotonic() < deadline:
            with contextlib.suppress(TimeoutError):
                silent.accept()[0].close()
        assert not thread.is_alive()


def test_a_framework_without_data_parallel_training_is_one_line(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "labcli", "train", "--task", "cartpole", "--framework", "sb3",
         "--nproc", "2"], capture_output=True, text=True,
        env={**os.environ, "LAB_LOGS_DIR": str(tmp_path)})
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "error: framework 'sb3' has no data-parallel training (2 ranks asked for) (train it in "
        "one process, or use rsl_rl or skrl)"]
    assert not any(tmp_path.iterdir())


# Two ranks, as torchrun starts them -----------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rank(rank: int, tmp: str, framework: str, port: int, late_sigterm: bool = False) -> None:
    """One rank: torchrun's variables, then `lab train` as a library call. Every checkpoint is
    also written by every rank into tmp/rank<r>/ (a spy on RunContext.save, through the
    framework's own save), so that the ranks' agents can be compared. `late_sigterm`: rank 1
    is sent SIGTERM just after the ranks agreed, after iteration 1, that none was stopped."""
    os.environ.update(RANK=str(rank), LOCAL_RANK=str(rank), WORLD_SIZE="2",
                      LOCAL_WORLD_SIZE="2", MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    from labcli.runs import context, distributed, training

    if late_sigterm and rank == 1:
        agree = distributed.agreed_stop

        def agree_then_receive_sigterm(signum, device):
            agreed = agree(signum, device)
            if signum is None:
                signal.raise_signal(signal.SIGTERM)
            return agreed

        distributed.agreed_stop = agree_then_receive_sigterm

    original = context.RunContext.save

    def save_on_every_rank(self, save):
        original(self, save)
        folder = Path(tmp, f"rank{rank}", str(self.iteration))
        folder.mkdir(parents=True, exist_ok=True)
        save(folder / "agent.pt")

    context.RunContext.save = save_on_every_rank
    outcome = training.train("cartpole", framework, num_envs=ENVS, max_iterations=ITERATIONS,
                             device="cpu", backend="cpu", overrides=SMALL[framework],
                             logs_dir=Path(tmp, f"logs{rank}"), console=Console(file=io.StringIO()))
    Path(tmp, f"summary{rank}.json").write_text(json.dumps(outcome.summary))
    # The group is gone with its threads once training returns: a group that outlived
    # destroy_process_group ran gloo's threads into the interpreter's teardown, where a rank
    # now and then aborted at exit.
    assert not torch.distributed.is_initialized()
    assert not [name for name in _native_threads() if "gloo" in name]


def _native_threads() -> list[str]:
    tasks = Path("/proc/self/task")
    return [(task / "comm").read_text().strip() for task in tasks.iterdir()] if tasks.exists() \
        else []


def _tensors(value, prefix=""):
    """Every tensor in a checkpoint's nested dicts and lists, by path."""
    if isinstance(value, torch.Tensor):
        yield prefix, value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from _tensors(item, f"{prefix}/{key}")
    elif isinstance(value, list | tuple):
        for i, item in enumerate(value):
            yield from _tensors(item, f"{prefix}/{i}")


@pytest.mark.parametrize("framework", ["rsl_rl", "skrl"])
def test_two_gloo_ranks_train_one_agent(tmp_path, framework):
    mp.start_processes(_rank, args=(str(tmp_path), framework, _free_port()), nprocs=2,
                       start_method="spawn")
    # The agents of both ranks are the same after every update: parameters, normalizers and
    # the optimizer's state.
    for iteration in range(1, ITERATIONS + 1):
        agents = [dict(_tensors(read_torch_file(tmp_path / f"rank{r}" / str(iteration) /
                                                "agent.pt", "cpu"))) for r in (0, 1)]
        assert agents[0].keys() == agents[1].keys() and len(agents[0]) > 6
        for name, tensor in agents[0].items():
            assert torch.equal(tensor, agents[1][name]), (iteration, name)
        if iteration > 1:
            before = dict(_tensors(read_torch_file(
                tmp_path / "rank0" / str(iteration - 1) / "agent.pt", "cpu")))
            assert any(not torch.equal(t, before[n]) for n, t in agents[0].items())
    # Rank 0 alone wrote a run dir; its steps are both ranks' envs'.
    assert not (tmp_path / "logs1").exists()
    (run_dir,) = (tmp_path / "logs0" / framework / "cartpole").iterdir()
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == rundir.FINISHED
    assert summary["steps"] == ITERATIONS * STEPS_PER_ENV * ENVS * 2
    assert json.loads((run_dir / rundir.MANIFEST).read_text())["ranks"] == 2
    fw = registry.get_framework(framework)
    assert [c.iteration for c in fw.checkpoints(run_dir)] == list(range(1, ITERATIONS + 1))
    # Each rank stepped its own episodes (seeds apart), saved beside rank 0's for a resume.
    state = snapshot.load(snapshot.path_of(run_dir, ITERATIONS))
    (other,) = state["ranks"]
    assert not torch.equal(state["env"]["qpos"], other["env"]["qpos"])


def test_a_signal_just_after_the_ranks_agreed_counts_at_the_next_iteration(tmp_path):
    """Decided on its own flag, rank 1 would stop after iteration 1 and leave rank 0 waiting in
    iteration 2's update; both stop after iteration 2 instead, checkpointed."""
    mp.start_processes(_rank, args=(str(tmp_path), "rsl_rl", _free_port(), True), nprocs=2,
                       start_method="spawn")
    summaries = [json.loads((tmp_path / f"summary{r}.json").read_text()) for r in (0, 1)]
    assert [(s["state"], s["iterations"], s["signal"]) for s in summaries] == [
        (rundir.INTERRUPTED, 2, signal.SIGTERM)] * 2
    (run_dir,) = (tmp_path / "logs0" / "rsl_rl" / "cartpole").iterdir()
    assert json.loads((run_dir / rundir.SUMMARY).read_text())["checkpoint"] == "model_2.pt"


# Two ranks, as `lab train --nproc 2` starts them ----------------------------------------------
ENDLESS = ["--backend", "cpu", "--num-envs", "8", "--max-iterations", "1000000", *(
    arg for setting in SMALL["rsl_rl"] for arg in ("--set", setting))]


def _start(logs: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "labcli", "train", "--task", "cartpole", "--framework", "rsl_rl",
         "--nproc", "2", *args],
        # A rank that aborts (a C++ terminate) then shows where it was, in the failure's stderr.
        env={**os.environ, "LAB_LOGS_DIR": str(logs), "PYTHONFAULTHANDLER": "1"},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _run_dir_with_checkpoints(logs: Path, at_least: int, proc: subprocess.Popen) -> Path:
    fw = registry.get_framework("rsl_rl")
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        for run_dir in logs.glob("rsl_rl/cartpole/*"):
            if len(fw.checkpoints(run_dir)) >= at_least:
                return run_dir
        time.sleep(0.1)
    raise AssertionError("no checkpoint written")


def _rank_pid(launcher: int, rank: int) -> int:
    """The pid of `rank` among the launcher's children (Linux: their environments)."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            environ = (stat.parent / "environ").read_bytes().split(b"\0")
        except (OSError, IndexError, ValueError):
            continue
        if parent == launcher and f"RANK={rank}".encode() in environ:
            return int(stat.parent.name)
    raise AssertionError(f"rank {rank} not found")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds ranks through /proc")
def test_a_killed_rank_fails_the_run_within_seconds(tmp_path):
    proc = _start(tmp_path, *ENDLESS)
    run_dir = _run_dir_with_checkpoints(tmp_path, 2, proc)
    os.kill(_rank_pid(proc.pid, 1), signal.SIGKILL)
    t0 = time.monotonic()
    _, err = proc.communicate(timeout=60)
    assert time.monotonic() - t0 < 10
    assert proc.returncode == 1
    # One line: the launcher's, naming the rank that ended the run; rank 0, which lost it,
    # records why in the summary and says nothing.
    (line,) = [line for line in err.strip().splitlines() if line.startswith("error:")]
    assert line.startswith("error: rank 1 was ended by SIGKILL; the other ranks were stopped"), err
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == rundir.FAILED and "another rank" in summary["error"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds ranks through /proc")
def test_ctrl_c_checkpoints_every_rank_and_the_run_resumes(tmp_path):
    proc = _start(tmp_path, *ENDLESS)
    run_dir = _run_dir_with_checkpoints(tmp_path, 2, proc)
    proc.send_signal(signal.SIGINT)  # as Ctrl-C reaches the launcher (the ranks have sessions)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "torch" not in err, err  # torch's elastic agent logged the Ctrl-C as a death signal
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == rundir.INTERRUPTED
    stopped = summary["iterations"]
    assert summary["checkpoint"] == f"model_{stopped}.pt"
    assert len(snapshot.load(snapshot.path_of(run_dir, stopped))["ranks"]) == 1

    resumed = _start(tmp_path, "--backend", "cpu", "--checkpoint", "latest", "--max-iterations",
                     str(stopped + 2))
    out, err = resumed.communicate(timeout=120)
    assert resumed.returncode == 0, err
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == rundir.FINISHED and summary["iterations"] == stopped + 2
    assert summary["steps"] == (stopped + 2) * STEPS_PER_ENV * 8 * 2
    assert "note:" not in err  # every rank went on with its own episodes
    assert "Synchronizing" not in out  # RSL-RL's line of each rank, between lab's progress lines


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds ranks through /proc")
def test_ranks_stop_with_a_checkpoint_when_their_launcher_is_killed(tmp_path):
    """SIGKILL, or the OOM killer, gives the launcher no chance to stop its ranks: they stop
    themselves, as SIGTERM stops them, instead of training on unwatched."""
    proc = _start(tmp_path, *ENDLESS)
    run_dir = _run_dir_with_checkpoints(tmp_path, 2, proc)
    ranks = [_rank_pid(proc.pid, rank) for rank in (0, 1)]
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 15
    while any(Path(f"/proc/{pid}").exists() for pid in ranks):
        assert time.monotonic() < deadline, "the ranks outlived their launcher by 15 s"
        time.sleep(0.1)
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == rundir.INTERRUPTED
    assert summary["checkpoint"] == f"model_{summary['iterations']}.pt"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds ranks through /proc")
def test_sigterm_to_one_rank_stops_them_all_with_a_checkpoint(tmp_path):
    proc = _start(tmp_path, *ENDLESS)
    run_dir = _run_dir_with_checkpoints(tmp_path, 2, proc)
    os.kill(_rank_pid(proc.pid, 1), signal.SIGTERM)  # a scheduler preempting one process
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == rundir.INTERRUPTED
    assert summary["checkpoint"] == f"model_{summary['iterations']}.pt"


def test_torchrun_starts_the_same_run(tmp_path):
    """The documented equivalent of `lab train --nproc 2`: torchrun's own launcher."""
    result = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
         "-m", "labcli", "train", "--task", "cartpole", "--framework", "skrl", "--backend",
         "cpu", "--num-envs", "8", "--max-iterations", "2", *(
             arg for setting in SMALL["skrl"] for arg in ("--set", setting))],
        capture_output=True, text=True, env={**os.environ, "LAB_LOGS_DIR": str(tmp_path)},
        timeout=120)
    assert result.returncode == 0, result.stderr
    (run_dir,) = (tmp_path / "skrl" / "cartpole").iterdir()
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == rundir.FINISHED
    assert summary["steps"] == 2 * STEPS_PER_ENV * 8 * 2
    assert result.stdout.count(str(run_dir)) == 1  # rank 0 alone says where the run is


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds ranks through /proc")
def test_a_second_writer_of_a_multi_rank_run_is_refused_in_one_line(tmp_path):
    """Rank 0 refuses to write a run another process writes; rank 1, which then loses rank 0,
    adds no line of its own."""
    first = _start(tmp_path, *ENDLESS)
    try:
        _run_dir_with_checkpoints(tmp_path, 1, first)
        second = _start(tmp_path, *ENDLESS, "--checkpoint", "latest")
        _, err = second.communicate(timeout=120)
    finally:
        first.send_signal(signal.SIGINT)
        first.communicate(timeout=60)
    assert second.returncode == 2, err
    (line,) = [line for line in err.strip().splitlines() if line.startswith("error:")]
    assert " is being written by process " in line, err
