"""Handling a run dir's files as a user (or an attacker) would, for the tests."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path


def remanifest(run_dir: Path, iteration: int) -> None:
    """Make checkpoint `iteration`'s manifest match its files again, as someone editing them by
    hand would: files gone are dropped from it, planted companions (`*_N.pkl`) added."""
    path = run_dir / f"checkpoint_{iteration}.json"
    manifest = json.loads(path.read_text())
    names = [name for name in manifest["files"] if (run_dir / name).exists()]
    names += [p.name for p in run_dir.glob(f"*_{iteration}.pkl")]
    manifest["files"] = {name: _entry(run_dir / name) for name in names}
    path.write_text(json.dumps(manifest))


def _entry(path: Path) -> dict:
    data = path.read_bytes()
    return {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}


def copy_checkpoint(source: Path, iteration: int, target: Path, as_iteration: int) -> None:
    """Checkpoint `iteration` of run `source` into run `target` as `as_iteration`, with its
    manifest: a whole checkpoint, as copying a run's files by hand would make one."""
    manifest = json.loads((source / f"checkpoint_{iteration}.json").read_text())
    renamed = {}
    for name, entry in manifest["files"].items():
        new = name.replace(f"_{iteration}.", f"_{as_iteration}.")
        (target / new).write_bytes((source / name).read_bytes())
        renamed[new] = entry
    manifest.update(iteration=as_iteration, files=renamed)
    (target / f"checkpoint_{as_iteration}.json").write_text(json.dumps(manifest))


def snapshot_of(root: Path) -> dict[Path, int]:
    """Every file and directory under `root` with its modification time: equal snapshots mean
    nothing was written."""
    return {p: p.stat().st_mtime_ns for p in root.rglob("*")}


def kill_when_writing(script: str, *args: str) -> None:
    """Run the Python `script` with `args` and SIGKILL it as soon as it prints "writing" (the
    scripts print it from inside a write they have slowed down)."""
    proc = subprocess.Popen([sys.executable, "-c", script, *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "writing", proc.stderr.read()
        proc.kill()
        proc.wait(timeout=30)
    finally:
        proc.kill()
