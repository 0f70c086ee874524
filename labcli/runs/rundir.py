"""Run directories, logs/<framework>/<task>/<YYYY-mm-dd_HH-MM-SS>[_<name>]/, and their files."""

from __future__ import annotations

import json
import os
import re
import socket
import tempfile
import time
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import yaml

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


def read_json(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text())


@dataclass
class Run:
    dir: Path

    @property
    def name(self) -> str:
        return self.dir.name

    def manifest(self) -> dict[str, Any]:
        path = self.dir / MANIFEST
        if not path.is_file():
            raise LabError(f"{self.dir} is not a lab run: it has no {MANIFEST}",
                           "pass a directory made by `lab train`")
        try:
            return read_json(path)
        except json.JSONDecodeError as exc:
            raise LabError(f"{path} is not valid JSON: {exc}") from exc

    def params(self, which: str) -> dict[str, Any]:
        path = self.dir / which
        try:
            data = yaml.safe_load(path.read_text())
        except FileNotFoundError as exc:
            raise LabError(f"{path} is missing", "the run dir is incomplete") from exc
        except yaml.YAMLError as exc:
            first = str(exc).splitlines()[0]
            raise LabError(f"{path} is not valid YAML: {first}", "fix or restore the file") from exc
        if not isinstance(data, dict):
            raise LabError(f"{path} must hold a mapping of settings, not {type(data).__name__}")
        return data

    def update_manifest(self, **changes: Any) -> None:
        data = self.manifest()
        data.update(changes)
        write_json(self.dir, MANIFEST, data)

    def summary(self) -> dict[str, Any] | None:
        path = self.dir / SUMMARY
        if not path.is_file():
            return None
        try:
            return read_json(path)
        except json.JSONDecodeError as exc:
            raise LabError(f"{path} is not valid JSON: {exc}") from exc


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


def _alive(manifest: dict[str, Any]) -> bool:
    pid = manifest.get("pid")
    if not isinstance(pid, int):
        return False
    if manifest.get("host") not in (None, socket.gethostname()):
        return True  # on another machine: cannot be checked from here, trust the record
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, owned by another user
    started = manifest.get("pid_started")
    return started is None or _process_start(pid) in (started, None)


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
    stamp = datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    base = f"{stamp}_{name}" if name else stamp
    for n in range(1000):
        path = parent / (base if n == 0 else f"{base}-{n}")
        try:
            path.mkdir(mode=files.DIR_MODE)
        except FileExistsError:
            continue
        return Run(path)
    raise LabError(f"too many runs named {base} in {parent}")


def find(logs_dir: Path, task: str | None = None, framework: str | None = None) -> list[Run]:
    """Runs under `logs_dir`, newest first, optionally filtered."""
    runs = []
    for manifest in logs_dir.glob(f"{framework or '*'}/{task or '*'}/*/{MANIFEST}"):
        runs.append(Run(manifest.parent))
    return sorted(runs, key=lambda r: (r.dir.name, r.dir.stat().st_mtime), reverse=True)


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
    started: str
    state: str
    steps: int | None = None
    wall_time_s: float | None = None
    mean_return: float | None = None
    success_rate: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "dir": str(self.dir)}


_STAMPED = re.compile(r"\d{4}-\d{2}-\d{2}_\d{2}-\d{2}-\d{2}_?(.*)")


def run_name(run_dir: Path) -> str:
    """The `--run-name` part of a run dir's name, after its time stamp; "" if it has none."""
    match = _STAMPED.fullmatch(run_dir.name)
    return match.group(1) if match else run_dir.name


def table(logs_dir: Path, task: str | None = None, framework: str | None = None,
          state: str | None = None) -> list[RunRow]:
    """Every run under `logs_dir`, newest first, filtered by task, framework and state."""
    rows = []
    for run in find(logs_dir, task, framework):
        try:
            manifest = run.manifest()
            summary = run.summary()
        except (LabError, json.JSONDecodeError, OSError):
            continue  # a run dir being written or damaged is not a row
        row = RunRow(dir=run.dir, task=manifest.get("task", "?"),
                     framework=manifest.get("framework", "?"),
                     started=manifest.get("started", ""), state=run_state(run))
        if summary is not None:
            row.steps, row.wall_time_s = summary.get("steps"), summary.get("wall_time_s")
            row.mean_return, row.success_rate = (summary.get("mean_return"),
                                                 summary.get("success_rate"))
        elif row.state == RUNNING and row.started:
            row.wall_time_s = round(time.time() - datetime.fromisoformat(row.started)
                                    .timestamp(), 1)
        if state is None or row.state == state:
            rows.append(row)
    return rows
