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

from labcli.errors import LabError

MANIFEST = "run.json"
SUMMARY = "summary.json"
ENV_PARAMS = "params/env.yaml"
AGENT_PARAMS = "params/agent.yaml"
COMMAND = "command.txt"
EXPORTED = "exported"


def default_logs_dir() -> Path:
    return Path(os.environ.get("LAB_LOGS_DIR", "logs"))


def write_atomic(path: Path, text: str) -> None:
    """Write via a temporary file and a rename, so a reader never sees half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json(path: Path, data: dict[str, Any]) -> None:
    write_atomic(path, json.dumps(data, indent=2, sort_keys=False) + "\n")


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
        write_json(self.dir / MANIFEST, data)

    def summary(self) -> dict[str, Any] | None:
        path = self.dir / SUMMARY
        return read_json(path) if path.is_file() else None


def create(logs_dir: Path, framework: str, task: str, name: str | None = None) -> Run:
    """Make a new run dir; two runs started in the same second get distinct dirs."""
    parent = logs_dir / framework / task
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LabError(f"cannot create the run directory under {parent}: {exc.strerror}",
                       "pass a writable --logs-dir") from exc
    if not os.access(parent, os.W_OK):
        raise LabError(f"{parent} is not writable", "pass a writable --logs-dir")
    stamp = datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    base = f"{stamp}_{name}" if name else stamp
    for n in range(1000):
        path = parent / (base if n == 0 else f"{base}-{n}")
        try:
            path.mkdir()
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
RUNNING, CRASHED = "running", "crashed"
# A process that started this long after its run's recorded start is not the run's: its pid
# was reused after the run died (the start is recorded to the second).
PID_REUSE_SLACK_S = 5.0


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


def state_of(manifest: dict[str, Any], summary: dict[str, Any] | None) -> str:
    """The summary's state once training ended; while the manifest says "running", the run
    is running only if its process is alive on this host, else it died without a summary:
    "crashed" (killed, out of memory, power lost)."""
    state = (summary or manifest).get("state", RUNNING)
    if state != RUNNING:
        return state
    alive = (manifest.get("host") == socket.gethostname()
             and _process_alive(manifest.get("pid"), manifest.get("started")))
    return RUNNING if alive else CRASHED


def _process_alive(pid: Any, started: str | None) -> bool:
    if not isinstance(pid, int) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        pass
    began = _process_start(pid)
    if began is None or started is None:
        return True
    try:
        recorded = datetime.fromisoformat(started).timestamp()
    except ValueError:
        return True
    return began <= recorded + PID_REUSE_SLACK_S


def _process_start(pid: int) -> float | None:
    """When process `pid` started (Unix time), from Linux's /proc; None elsewhere."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        boot = next(line for line in Path("/proc/stat").read_text().splitlines()
                    if line.startswith("btime "))
    except (OSError, StopIteration):
        return None
    # Field 22 (start time in clock ticks after boot) counted after the ")" that closes the
    # command name, which may itself hold spaces.
    ticks = int(stat.rsplit(")", 1)[1].split()[19])
    return int(boot.split()[1]) + ticks / os.sysconf("SC_CLK_TCK")


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
                     started=manifest.get("started", ""), state=state_of(manifest, summary))
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
