"""Which checkpoint a command means: `latest`, a file, or a run dir's newest complete one. A
checkpoint is complete when it reads back whole: a truncated or damaged file (copied half-way,
written by an older lab without renames) is passed over."""

from __future__ import annotations

import zipfile
from pathlib import Path

from labcli.errors import LabError
from labcli.plugins.framework import Checkpoint, FrameworkSpec
from labcli.runs import rundir

LATEST = "latest"
# SB3's .zip and torch.save's .pt are zip containers, whose checksums tell a damaged file.
ZIP_SUFFIXES = (".zip", ".pt", ".pth")


def complete(path: Path) -> bool:
    """Whether `path` reads back whole; files of other formats are taken as they are."""
    try:
        with zipfile.ZipFile(path) as archive:
            return archive.testzip() is None
    except (zipfile.BadZipFile, OSError, EOFError):
        return path.suffix not in ZIP_SUFFIXES and path.is_file()


def latest_complete(fw: FrameworkSpec, run_dir: Path) -> Checkpoint | None:
    """The newest complete checkpoint in `run_dir`."""
    for found in reversed(fw.checkpoints(run_dir)):
        if complete(found.path):
            return found
    return None


def find(value: str, logs_dir: Path, task: str, fw: FrameworkSpec) -> tuple[rundir.Run,
                                                                            Checkpoint]:
    """`latest` (newest complete checkpoint of the newest run of task+framework) or a path; a
    run dir gives its newest complete checkpoint."""
    if value == LATEST:
        for run in rundir.find(logs_dir, task, fw.name):
            found = latest_complete(fw, run.dir)
            if found is not None:
                return run, found
        raise LabError(f"no complete checkpoint of a {fw.name} run of '{task}' in {logs_dir}",
                       "train first, or pass --checkpoint PATH")
    path = Path(value)
    if path.is_dir():
        found = latest_complete(fw, path)
        if found is None:
            broken = ", ".join(c.path.name for c in fw.checkpoints(path))
            raise LabError(f"{path} holds no complete {fw.name} checkpoint"
                           + (f" ({broken}: truncated or damaged)" if broken else ""),
                           f"expected files like {fw.checkpoint_path(path, 100).name}")
        return rundir.open_run(path), found
    if not path.is_file():
        raise LabError(f"checkpoint {path} does not exist", "pass a file, a run dir or 'latest'")
    match = [c for c in fw.checkpoints(path.parent) if c.path.name == path.name]
    if not match:
        raise LabError(f"{path.name} is not a {fw.name} checkpoint name",
                       f"expected a name like {fw.checkpoint_path(path.parent, 100).name}")
    if not complete(path):
        raise LabError(f"checkpoint {path} is incomplete (truncated or damaged)",
                       "pick another checkpoint, or pass the run dir for its newest complete one")
    return rundir.open_run(path.parent), match[0]


def check_run_matches(run: rundir.Run, task: str, framework: str) -> None:
    manifest = run.manifest()
    if manifest.get("task") != task or manifest.get("framework") != framework:
        raise LabError(
            f"run {run.dir} is a {manifest.get('framework')} run of '{manifest.get('task')}', "
            f"not a {framework} run of '{task}'",
            "pass a checkpoint of the same task and framework")
