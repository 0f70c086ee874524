"""Run directories, logs/<framework>/<task>/<YYYY-mm-dd_HH-MM-SS>[_<name>]/, and their files."""

from __future__ import annotations

import json
import os
import tempfile
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
