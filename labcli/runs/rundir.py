"""Run directories, logs/<framework>/<task>/<YYYY-mm-dd_HH-MM-SS>[_<name>]/, and their files."""

from __future__ import annotations

import contextlib
import json
import os
import re
import socket
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from labcli import files
from labcli.errors import LabError

MANIFEST = "run.json"
SUMMARY = "summary.json"
ENV_PARAMS = "params/env.yaml"
AGENT_PARAMS = "params/agent.yaml"
COMMAND = "command.txt"
EXPORTED = "exported"

# A run's state, in summary.json and run.json. "running" is written when training starts; the
# others when it ends. A run whose process died without saying so reads as "failed".
RUNNING, FINISHED, INTERRUPTED, FAILED = "running", "finished", "interrupted", "failed"
STATES = (RUNNING, FINISHED, INTERRUPTED, FAILED)
DAMAGED = "damaged"  # only in `lab runs`: a run whose run.json or summary.json cannot be read


def default_logs_dir() -> Path:
    return Path(os.environ.get("LAB_LOGS_DIR", "logs"))


# A run name is one path component of a directory name: no separators, no spaces or control
# characters, not hidden and not an option, short enough for any file system with the time stamp.
RUN_NAME = re.compile(r"[^\s\x00-\x1f\x7f/\\:.\-][^\s\x00-\x1f\x7f/\\:]{0,99}")


def check_run_name(name: str) -> None:
    if not RUN_NAME.fullmatch(name):
        shown = repr(name) if len(name) <= 60 else f"{name[:40]!r}... ({len(name)} characters)"
        raise LabError(f"--run-name {shown} is not a plain name",
                       "use at most 100 letters, digits and punctuation other than / \\ :, no "
                       "spaces, not starting with . or -")


def write_atomic(run_dir: Path, name: str, text: str) -> None:
    """`name` (e.g. params/env.yaml) in `run_dir`, atomically and durably, with the user's umask,
    never through a link inside the run dir (labcli/files.py)."""
    files.write_atomic(run_dir / name, text, below=run_dir)


def write_json(run_dir: Path, name: str, data: dict[str, Any]) -> None:
    write_atomic(run_dir, name, json.dumps(data, indent=2, sort_keys=False) + "\n")


NUMBER = (int, float)
# The fields of run.json and summary.json that lab reads, and the types they must have: a file
# edited or damaged into another shape is refused by name, never a traceback further on.
MANIFEST_FIELDS = {"task": str, "framework": str, "seed": int, "device": str, "backend": str,
                   "num_envs": int, "started": str, "first_started": str, "pid": int,
                   "host": str, "pid_started": (int, type(None)), "state": str, "versions": dict,
                   "resumed_from": str, "sessions": list, "ranks": int, "model": dict}
SUMMARY_FIELDS = {"state": str, "iterations": int, "steps": int, "wall_time_s": NUMBER,
                  "total_wall_time_s": NUMBER, "mean_return": (*NUMBER, type(None)),
                  "mean_episode_length": (*NUMBER, type(None)),
                  "success_rate": (*NUMBER, type(None)),
                  "terrain_level": (*NUMBER, type(None)), "checkpoint": (str, type(None)),
                  "finished": str, "error": str, "signal": int}


def read_json(path: Path, fields: dict[str, Any]) -> dict[str, Any]:
    """A JSON object whose `fields`, where present, have their types; a LabError naming the
    file and what is wrong otherwise."""
    try:
        data = files.load_json(files.read_bytes(path))
    except files.Unreadable as exc:
        raise LabError(f"{path} {exc}", "restore or delete the file") from None
    if not isinstance(data, dict):
        raise LabError(f"{path} is damaged: it holds a JSON {type(data).__name__}, not an "
                       "object", "restore or delete the file")
    for key, types in fields.items():
        value = data.get(key)
        if key in data and (not isinstance(value, types) or isinstance(value, bool)
                            and bool not in _flat(types)):
            raise LabError(f"{path} is damaged: its {key!r} is {value!r}",
                           "restore or delete the file")
    return data


def _flat(types: Any) -> tuple[type, ...]:
    return types if isinstance(types, tuple) else (types,)


@dataclass
class Run:
    dir: Path

    @property
    def name(self) -> str:
        return self.dir.name

    def manifest(self) -> dict[str, Any]:
        path = self.dir / MANIFEST
        if not path.exists():
            raise LabError(f"{self.dir} is not a lab run: it has no {MANIFEST}",
                           "pass a directory made by `lab train`")
        return read_json(path, MANIFEST_FIELDS)

    def identity(self) -> tuple[str, str]:
        """The run's task and framework, as its run.json records them."""
        manifest = self.manifest()
        task, framework = manifest.get("task"), manifest.get("framework")
        if task is None or framework is None:
            raise LabError(f"{self.dir / MANIFEST} is damaged: it names no "
                           f"{'task' if task is None else 'framework'}",
                           "restore or delete the file")
        return task, framework

    def params(self, which: str) -> dict[str, Any]:
        path = self.dir / which
        if not path.exists():
            raise LabError(f"{path} is missing", "the run dir is incomplete")
        try:
            data = files.load_yaml(files.read_text(path))
        except files.Unreadable as exc:
            raise LabError(f"{path} {exc}", "fix or restore the file") from None
        if not isinstance(data, dict):
            raise LabError(f"{path} must hold a mapping of settings, not {type(data).__name__}",
                           "fix or restore the file")
        return data

    def update_manifest(self, **changes: Any) -> None:
        data = self.manifest()
        data.update(changes)
        write_json(self.dir, MANIFEST, data)

    def summary(self) -> dict[str, Any] | None:
        path = self.dir / SUMMARY
        if not path.exists():
            return None
        return read_json(path, SUMMARY_FIELDS)


def run_state(run: Run) -> str:
    """"running", "finished", "interrupted" or "failed". A run recorded as running whose process
    is gone (SIGKILL, out of memory, a reboot) is "failed": it never wrote its end."""
    summary = run.summary() or {}
    manifest = run.manifest()
    state = summary.get("state") or manifest.get("state")
    if state == RUNNING and not _alive(manifest):
        return FAILED
    return state if state in STATES else FAILED


def process_identity() -> dict[str, Any]:
    """What tells this process apart from any other, later, with the same pid: the pid, the
    host, and the process's start time where the OS gives it."""
    return {"pid": os.getpid(), "host": socket.gethostname(),
            "pid_started": _process_start(os.getpid())}


def _process_start(pid: int) -> int | None:
    """Clock ticks since boot at which `pid` started (Linux), None elsewhere or when gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # The command name (field 2) may hold spaces and parentheses: count from its closing one.
    return int(stat[stat.rindex(")") + 2:].split()[19])


PID_MAX = 1 << 22  # Linux's largest pid_max


def _alive(manifest: dict[str, Any]) -> bool:
    pid = manifest.get("pid")
    if not isinstance(pid, int) or not 0 < pid <= PID_MAX:
        return False
    if manifest.get("host") not in (None, socket.gethostname()):
        return True  # on another machine: cannot be checked from here, trust the record
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, owned by another user
    # Where the OS tells when a process started, a record without that time cannot be told
    # from a later process that reuses the pid (pid 1 always exists): not this run's.
    return _process_start(pid) in (manifest.get("pid_started"), None)


@contextlib.contextmanager
def writing(run: Run) -> Iterator[None]:
    """Hold the run while this process writes it: a second `lab train` of the same run is
    refused at once, naming the process that holds it."""
    with holding(run.dir, lambda: LabError(
            f"run {run.dir} is being written by {_holder(run)}",
            "wait for it to end, or stop it first; two writers would mix their checkpoints")):
        yield


@contextlib.contextmanager
def holding(directory: Path, busy: Callable[[], LabError]) -> Iterator[None]:
    """Hold `directory` while this process writes it, or raise `busy()` at once where another
    does: an advisory lock (flock) on the directory itself, which writes nothing and which the
    OS releases when its process ends, however."""
    try:
        import fcntl
    except ImportError:  # Windows: no flock; nothing there is guarded against two writers
        yield
        return
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0)
                     | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise LabError(f"{directory} cannot be opened: {exc.strerror}") from exc
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise busy() from None
        yield
    finally:
        os.close(fd)  # releases the lock


def _holder(run: Run) -> str:
    """Who holds the run, as its run.json says once the holder has written it."""
    try:
        manifest = run.manifest()
    except LabError:
        return "another process"
    if manifest.get("state") != RUNNING or not _alive(manifest):
        return "another process"
    return (f"process {manifest['pid']} on {manifest.get('host', 'this host')} (lab train, "
            f"started {manifest.get('started', '?')})")


def check_writable(path: Path) -> None:
    """Fail now, not after start-up, where `path` (or the directories it would be made in)
    cannot be written: by trying, since permission bits do not tell read-only mounts or
    immutable files, and root ignores them."""
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise LabError(f"cannot write runs under {path}: {existing} is not a directory",
                       "pass a writable --logs-dir")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as exc:
        raise LabError(f"cannot write runs under {path}: {existing} is not writable "
                       f"({exc.strerror})", "pass a writable --logs-dir, or fix its permissions"
                       ) from exc


def create(logs_dir: Path, framework: str, task: str, name: str | None = None) -> Run:
    """Make a new run dir; two runs started in the same second get distinct dirs."""
    if name is not None:
        check_run_name(name)
    parent = logs_dir / framework / task
    try:
        parent.mkdir(parents=True, exist_ok=True, mode=files.DIR_MODE)
    except OSError as exc:
        raise LabError(f"cannot create the run directory under {parent}: {exc.strerror}",
                       "pass a writable --logs-dir") from exc
    check_writable(parent)
    return Run(unique_dir(parent, f"{stamp()}_{name}" if name else stamp()))


def unique_dir(parent: Path, base: str) -> Path:
    """A new directory `base` in `parent`, or `base-1`, `base-2`... where it exists (two runs,
    or two plays' videos, in the same second)."""
    for n in range(1000):
        path = parent / (base if n == 0 else f"{base}-{n}")
        try:
            path.mkdir(mode=files.DIR_MODE)
        except FileExistsError:
            continue
        return path
    raise LabError(f"too many directories named {base} in {parent}")


def stamp() -> str:
    """Now, as the names of run dirs (and sweeps, plays' videos) begin: sorted by name, by
    time."""
    return datetime.now().strftime("%Y-%m-%d_%H-%M-%S")


def find(logs_dir: Path, task: str | None = None, framework: str | None = None) -> list[Run]:
    """Runs under `logs_dir`, newest first (by the time stamp in their names, then by when they
    last changed), optionally filtered."""
    runs = [Run(manifest.parent)
            for manifest in logs_dir.glob(f"{framework or '*'}/{task or '*'}/*/{MANIFEST}")]
    return sorted(runs, key=lambda r: (r.dir.name, _mtime(r.dir)), reverse=True)


def _mtime(path: Path) -> float:
    try:
        return path.stat().st_mtime
    except OSError:  # removed meanwhile
        return 0.0


def latest(logs_dir: Path, task: str | None = None, framework: str | None = None) -> Run:
    runs = find(logs_dir, task, framework)
    if not runs:
        what = " ".join(f"--{k} {v}" for k, v in (("task", task), ("framework", framework)) if v)
        raise LabError(f"no runs found in {logs_dir}{' for ' + what if what else ''}",
                       "train one first with `lab train`, or pass --run DIR")
    return runs[0]


def open_run(path: Path) -> Run:
    if not path.is_dir():
        raise LabError(f"run directory {path} does not exist", "pass a dir made by `lab train`")
    run = Run(path)
    run.manifest()
    return run


# The runs table (`lab runs`) ------------------------------------------------------------------

@dataclass
class RunRow:
    """One line of `lab runs`: the manifest and summary of a run, with its state checked."""

    dir: Path
    task: str
    framework: str
    started: str  # the run's first start: a resumed run keeps it
    state: str
    steps: int | None = None
    wall_time_s: float | None = None  # over all its sessions
    mean_return: float | None = None
    success_rate: float | None = None
    problem: str | None = None  # why a damaged run's files cannot be read

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "dir": str(self.dir)}


_STAMPED = re.compile(r"\d{4}-\d{2}-\d{2}_\d{2}-\d{2}-\d{2}_?(.*)")


def run_name(run_dir: Path) -> str:
    """The `--run-name` part of a run dir's name, after its time stamp; "" if it has none."""
    match = _STAMPED.fullmatch(run_dir.name)
    return match.group(1) if match else run_dir.name


def table(logs_dir: Path, task: str | None = None, framework: str | None = None,
          state: str | None = None) -> list[RunRow]:
    """Every run under `logs_dir`, newest first, filtered by task, framework and state. A run
    whose files cannot be read is a row of its own, state "damaged", saying which file and why:
    it never hides the others."""
    rows = []
    for run in find(logs_dir, task, framework):
        try:
            row = _row(run)
        except LabError as exc:
            row = RunRow(dir=run.dir, task=run.dir.parent.name,
                         framework=run.dir.parent.parent.name, started="", state=DAMAGED,
                         problem=str(exc))
        if state is None or row.state == state:
            rows.append(row)
    return rows


def _row(run: Run) -> RunRow:
    manifest, summary = run.manifest(), run.summary()
    started = manifest.get("first_started", manifest.get("started", ""))
    try:
        since = datetime.fromisoformat(started).timestamp() if started else None
    except ValueError:
        raise LabError(f"{run.dir / MANIFEST} is damaged: its start time is {started!r}",
                       "restore or delete the file") from None
    row = RunRow(dir=run.dir, task=manifest.get("task", "?"),
                 framework=manifest.get("framework", "?"), started=started,
                 state=run_state(run))
    if summary is not None:
        row.steps = summary.get("steps")
        row.wall_time_s = summary.get("total_wall_time_s", summary.get("wall_time_s"))
        row.mean_return, row.success_rate = summary.get("mean_return"), summary.get("success_rate")
    elif row.state == RUNNING and since is not None:
        row.wall_time_s = round(time.time() - since, 1)
    return row
