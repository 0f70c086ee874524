"""Checkpoints as sets of files, written whole or not at all, and which one a command means.

A checkpoint of iteration N is the framework's model file (`model_N.zip`, `model_N.pt`...), the
companions the framework writes beside it (SB3's `vecnormalize_N.json`), and lab's
`state_N.pt`. It is staged in a fresh private directory, checked, fsynced, renamed into place
file by file, and only then is its manifest `checkpoint_N.json` (every file's size and sha256)
written: a checkpoint is complete when its manifest is there and every file matches it, so a kill,
a full disk, a copy cut short or a damaged file can never make `latest` pick half a checkpoint.
Runs written before manifests existed are judged by their zip checksums."""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import tempfile
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from labcli import files
from labcli.errors import LabError
from labcli.plugins.framework import Checkpoint, FrameworkSpec
from labcli.runs import config, rundir

LATEST = "latest"
BEST = "best"
# The figures a checkpoint's manifest records: of the episodes that ended since the checkpoint
# before it, what `--checkpoint best` ranks by (success, then return).
SUCCESS, RETURN, EPISODES = "success_rate", "mean_return", "episodes"
MANIFEST_PREFIX = "checkpoint_"
# SB3's .zip and torch.save's .pt are zip containers, whose checksums tell a damaged file.
ZIP_SUFFIXES = (".zip", ".pt", ".pth")
MAX_MANIFEST_BYTES = 1 << 20
# A zip's end-of-central-directory record: its size without the comment, and its signature.
_END_RECORD, _END_SIGNATURE = 22, b"PK\x05\x06"


def manifest_path(directory: Path, iteration: int) -> Path:
    return directory / f"{MANIFEST_PREFIX}{iteration}.json"


def write(directory: Path, fw: FrameworkSpec, iteration: int, save: Callable[[Path], None],
          extra: Callable[[Path], None] | None = None,
          check: Callable[[Path], None] | None = None, below: Path | None = None,
          figures: dict[str, float] | None = None, durable: bool = True) -> Checkpoint:
    """Checkpoint `iteration` into `directory`: `save(path)` writes the framework's model at
    `path` (its final name, in a private staging directory) and any companions beside it;
    `extra(staging_dir)` adds lab's own files (the env state); `check(path)` may refuse the
    staged model by raising; then the set is published. Nothing is left behind when any of it
    fails. `directory` is a run dir, or (with `below`, the run dir) a directory inside one.
    `figures` (SUCCESS, RETURN, EPISODES) go into the manifest. Not `durable`: the files are
    not flushed to the disk (a checkpoint that only this process reads back)."""
    if below is not None:
        files.real_dir(directory, below=below)
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".tmp_checkpoint_{iteration}.", dir=directory))
    except OSError as exc:
        raise files.unwritable(directory, exc) from exc
    try:
        model = fw.checkpoint_path(staging, iteration)
        try:
            save(model)
            if extra is not None:
                extra(staging)
            if not model.is_file():
                raise RuntimeError(f"framework '{fw.name}' did not write its checkpoint at "
                                   f"{model}")
            if check is not None:
                check(model)
            _publish(staging, directory, iteration, fw.name, figures, durable)
            _drop_older_companions(directory, fw, iteration)
        except (OSError, RuntimeError, LabError) as exc:
            # The staging dir is lab's own: gone, it was removed under lab, whatever the
            # library (or the check reading the model back) said of its missing file (`rm -rf`
            # of the run dir empties it first).
            if not staging.is_dir():
                raise files.deleted(below or directory) from exc
            if isinstance(exc, LabError):
                raise
            error = files.failed_write(fw.checkpoint_path(directory, iteration), exc,
                                       root=below or directory)
            if error is None:
                raise
            raise error from exc
    finally:
        files.remove(staging)
    return Checkpoint(fw.checkpoint_path(directory, iteration), iteration)


def discard_staging(directory: Path) -> None:
    """Remove what a killed writer left staged in `directory`: never a checkpoint, only parts."""
    for path in directory.glob(f".tmp_{MANIFEST_PREFIX}*"):
        files.remove(path)


def _publish(staging: Path, directory: Path, iteration: int, framework: str,
             figures: dict[str, float] | None, durable: bool) -> None:
    entries = {}
    for path in sorted(staging.iterdir()):
        if not path.is_symlink() and not path.exists():  # listed, then removed under lab
            raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), str(path))
        if path.is_symlink() or not path.is_file():
            raise RuntimeError(f"a checkpoint holds only files, not {path.name}")
        if durable:
            files.fsync_file(path)
        entries[path.name] = {"bytes": path.stat().st_size, "sha256": files.sha256(path)}
    for name in entries:
        (staging / name).chmod(files.FILE_MODE)
        (staging / name).replace(directory / name)
    manifest = {"iteration": iteration, "framework": framework, "files": entries,
                **({"figures": figures} if figures else {})}
    files.write_atomic(manifest_path(directory, iteration), json.dumps(manifest, indent=2) + "\n",
                       below=directory)


def _drop_older_companions(directory: Path, fw: FrameworkSpec, iteration: int) -> None:
    """Remove `fw.newest_only`'s files of the checkpoints before `iteration`, each left
    complete: its manifest is rewritten without them before they go, so a kill in between
    leaves a complete checkpoint beside a file it no longer lists. A file that cannot be
    removed stays: it costs room, not work."""
    for prefix in fw.newest_only:
        for path in directory.glob(f"{prefix}*"):
            match = re.match(re.escape(prefix) + r"(\d+)\D", path.name)
            if match is None or int(match.group(1)) >= iteration:
                continue
            manifest = manifest_path(directory, int(match.group(1)))
            try:
                data = _read_manifest(manifest)
                if path.name in data["files"]:
                    del data["files"][path.name]
                    files.write_atomic(manifest, json.dumps(data, indent=2) + "\n",
                                       below=directory)
                files.remove(path)
            except (OSError, ValueError, UnicodeDecodeError, LabError):
                continue


def missing_companions(fw: FrameworkSpec, checkpoint: Checkpoint) -> list[str]:
    """What of `fw.newest_only` `checkpoint` does not hold (it was not its run's newest)."""
    directory, n = checkpoint.path.parent, checkpoint.iteration
    return [what for prefix, what in fw.newest_only.items()
            if not any(directory.glob(f"{prefix}{n}.*"))]


def rewrite(source: Path, fw: FrameworkSpec, iteration: int, target: Path,
            extra: Callable[[Path], None] | None = None) -> Checkpoint:
    """Write the complete checkpoint `iteration` of `source` again into the run dir `target`,
    durably, with `extra`'s files added (as `write`'s)."""
    names = _read_manifest(manifest_path(source, iteration))["files"]

    def save(model: Path) -> None:
        for name in names:
            shutil.copyfile(source / name, model.parent / name)

    return write(target, fw, iteration, save, extra)


def _read_manifest(path: Path) -> dict[str, Any]:
    """The manifest at `path`, or a ValueError saying why it is not one."""
    if path.is_symlink() or not path.is_file():
        raise ValueError("no manifest")
    try:
        data = files.load_json(files.read_bytes(path, MAX_MANIFEST_BYTES))
    except files.Unreadable as exc:
        raise ValueError(str(exc)) from None
    entries = data.get("files") if isinstance(data, dict) else None
    if not isinstance(entries, dict) or not all(
            isinstance(e, dict) and isinstance(e.get("bytes"), int)
            and isinstance(e.get("sha256"), str) for e in entries.values()):
        raise ValueError("malformed manifest")
    return data


def complete(fw: FrameworkSpec, checkpoint: Checkpoint) -> bool:
    """Whether `checkpoint` reads back whole: its manifest's files all there, as written."""
    return damage(fw, checkpoint) is None


def damage(fw: FrameworkSpec, checkpoint: Checkpoint) -> str | None:
    """What keeps `checkpoint` from reading back whole (a file of its manifest missing, or not
    as written), or None where nothing does."""
    directory = checkpoint.path.parent
    manifest_file = manifest_path(directory, checkpoint.iteration)
    try:
        manifest = _read_manifest(manifest_file)
    except (OSError, ValueError, UnicodeDecodeError):
        if any(directory.glob(f"{MANIFEST_PREFIX}*.json")):
            # A run with manifests: a checkpoint without one is half-written.
            return f"its manifest {manifest_file.name} is missing or unreadable"
        return None if _legacy_complete(checkpoint.path) else f"{checkpoint.path.name} is cut short"
    if checkpoint.path.name not in manifest["files"]:
        return f"its manifest {manifest_file.name} does not list {checkpoint.path.name}"
    for name, entry in manifest["files"].items():
        path = directory / name
        if path.is_symlink() or not path.is_file():
            return f"{name} is missing"
        if path.stat().st_size != entry["bytes"] or files.sha256(path) != entry["sha256"]:
            return f"{name} is not as written (size or sha256)"
    return None


def _legacy_complete(path: Path) -> bool:
    """A run from before manifests: its zip (SB3's, rl_games') read back whole. A zip cut
    short can still read as one, the last of the zips stored inside it (SB3 stores torch's
    whole): so the archive must begin at the file's first byte and end at its last."""
    try:
        with zipfile.ZipFile(path) as archive:
            infos = archive.infolist()
            if not infos or min(info.header_offset for info in infos) != 0:
                return False
            with path.open("rb") as file:
                file.seek(-_END_RECORD - len(archive.comment), os.SEEK_END)
                if file.read(4) != _END_SIGNATURE:
                    return False
            return archive.testzip() is None
    except (zipfile.BadZipFile, OSError, EOFError):
        return path.suffix not in ZIP_SUFFIXES and path.is_file()


def latest_complete(fw: FrameworkSpec, run_dir: Path) -> Checkpoint | None:
    """The newest complete checkpoint in `run_dir`."""
    for found in reversed(fw.checkpoints(run_dir)):
        if complete(fw, found):
            return found
    return None


def recorded_figures(run_dir: Path, iteration: int) -> dict[str, float] | None:
    """The figures checkpoint `iteration`'s manifest recorded, if it did and they are numbers."""
    try:
        figures = _read_manifest(manifest_path(run_dir, iteration)).get("figures")
    except ValueError:
        return None
    if not isinstance(figures, dict) or not all(
            isinstance(figures.get(k), (int, float)) and not isinstance(figures.get(k), bool)
            for k in (SUCCESS, RETURN, EPISODES)) or figures[EPISODES] <= 0:
        return None
    return figures


def _rank(figures: dict[str, float], iteration: int) -> tuple[float, float, int]:
    return figures[SUCCESS], figures[RETURN], iteration


def best_recorded(run_dir: Path) -> tuple[int, dict[str, float]] | None:
    """The iteration and figures of the best checkpoint `run_dir`'s manifests record (read,
    not verified: what `lab runs` shows)."""
    recorded = []
    for path in run_dir.glob(f"{MANIFEST_PREFIX}*.json"):
        number = path.stem.removeprefix(MANIFEST_PREFIX)
        figures = recorded_figures(run_dir, int(number)) if number.isdigit() else None
        if figures is not None:
            recorded.append((_rank(figures, int(number)), int(number), figures))
    return max(recorded)[1:] if recorded else None


def best_complete(fw: FrameworkSpec, run_dir: Path) -> Checkpoint | None:
    """The complete checkpoint in `run_dir` whose recorded figures are best: the highest
    success rate, then the highest return, then the newest."""
    ranked = []
    for found in fw.checkpoints(run_dir):
        figures = recorded_figures(run_dir, found.iteration)
        if figures is not None:
            ranked.append((_rank(figures, found.iteration), found))
    for _, found in sorted(ranked, key=lambda item: item[0], reverse=True):
        if complete(fw, found):
            return found
    return None


def pick(word: str, run: rundir.Run, fw: FrameworkSpec) -> Checkpoint:
    """`latest` or `best` of `run`, or a LabError saying why it has none."""
    found = (latest_complete if word == LATEST else best_complete)(fw, run.dir)
    if found is not None:
        return found
    if word == BEST and latest_complete(fw, run.dir) is not None:
        raise LabError(f"no checkpoint of run {run.dir} recorded its success and return (lab "
                       "records them with each checkpoint it writes now; this run's are older)",
                       "pass --checkpoint latest, or a checkpoint file")
    raise LabError(f"run {run.dir} holds no complete {fw.name} checkpoint",
                   "train first, or pass --checkpoint PATH")


def find(value: str, logs_dir: Path, task: str, fw: FrameworkSpec) -> tuple[rundir.Run,
                                                                            Checkpoint]:
    """`latest` or `best` (of the newest run of task+framework that has a complete checkpoint)
    or a path; a run dir gives its newest complete checkpoint."""
    if value in (LATEST, BEST):
        for run in rundir.find(logs_dir, task, fw.name):
            if latest_complete(fw, run.dir) is not None:
                return run, pick(value, run, fw)
        raise LabError(f"no complete checkpoint of a {fw.name} run of '{task}' in {logs_dir}",
                       "train first, or pass --checkpoint PATH")
    path = Path(value)
    if path.is_dir():
        found = latest_complete(fw, path)
        if found is None:
            found_any = fw.checkpoints(path)
            why = (f" (the newest, {found_any[-1].path.name}: {damage(fw, found_any[-1])})"
                   if found_any else "")
            raise LabError(f"{path} holds no complete {fw.name} checkpoint{why}",
                           f"expected files like {fw.checkpoint_path(path, 100).name} and "
                           "the files its manifest lists")
        return rundir.open_run(path), found
    if not path.is_file():
        raise LabError(f"checkpoint {path} does not exist",
                       "pass a file, a run dir, 'latest' or 'best'")
    match = [c for c in fw.checkpoints(path.parent) if c.path.name == path.name]
    if not match:
        raise LabError(f"{path.name} is not a {fw.name} checkpoint name",
                       f"expected a name like {fw.checkpoint_path(path.parent, 100).name}")
    why = damage(fw, match[0])
    if why is not None:
        raise LabError(f"checkpoint {path} is incomplete: {why}",
                       "pick another checkpoint, or pass the run dir for its newest complete one")
    return rundir.open_run(path.parent), match[0]


def check_run_matches(run: rundir.Run, task: str, framework: str) -> None:
    run_task, run_framework = run.identity()
    if (run_task, run_framework) != (task, framework):
        raise LabError(f"run {run.dir} is a {run_framework} run of '{run_task}', not a "
                       f"{framework} run of '{task}'",
                       "pass a checkpoint of the same task and framework")


def agent_config(fw: FrameworkSpec, run: rundir.Run) -> Any:
    """The run's agent config, as trained (params/agent.yaml): what rebuilds its networks."""
    data = run.params(rundir.AGENT_PARAMS)
    config.check_saved(fw.agent_config_class, "agent", run.dir / rundir.AGENT_PARAMS, data)
    return config.build(fw.agent_config_class, "agent", [data])
