"""A sweep dir's Ray Tune state is pickles (tuner.pkl, the experiment state, the searcher's),
which `lab sweep --resume` has Ray unpickle: running whatever code a planted or altered pickle
names. When a sweep's driver stops, lab signs every file Ray left in the dir with a key of the
user's (HMAC-SHA256); a resume first verifies them and refuses what does not: a sweep dir from
someone else, or changed since, is data, as run dirs are (docs/robustness.md, "Trust").

The key is `<config dir>/sweep.key` (`$LAB_CONFIG_DIR`, else `$XDG_CONFIG_HOME/lab`, else
`~/.config/lab`), made on first use, readable by its owner only."""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import secrets
from pathlib import Path

from labcli import files
from labcli.errors import LabError

SIGNATURE = "state.sig"
KEY_FILE = "sweep.key"
KEY_BYTES = 32


def config_dir() -> Path:
    explicit = os.environ.get("LAB_CONFIG_DIR")
    if explicit:
        return Path(explicit)
    base = os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config"
    return Path(base) / "lab"


def key() -> bytes:
    """The user's key, made (owner-only) the first time a sweep is signed."""
    path = config_dir() / KEY_FILE
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            data = path.read_bytes()
        else:
            data = secrets.token_bytes(KEY_BYTES)
            with os.fdopen(fd, "wb") as out:
                out.write(data)
    except OSError as exc:
        raise LabError(f"the key that signs sweep state, {path}, cannot be used: "
                       f"{exc.strerror or exc}",
                       "make its directory writable, or set LAB_CONFIG_DIR to one that is"
                       ) from None
    if len(data) != KEY_BYTES:
        raise LabError(f"the key that signs sweep state, {path}, is damaged "
                       f"({len(data)} bytes, not {KEY_BYTES})",
                       "remove it: a new one is made, and sweeps signed with the old one "
                       "cannot be resumed")
    return data


def _entries(sweep_dir: Path, own: frozenset[str]) -> dict[str, Path]:
    """Every entry below `sweep_dir` by its relative path, lab's own files at the top (`own`,
    which lab reads as YAML or JSON data) left out."""
    out = {}
    for folder, dirs, names in os.walk(sweep_dir):
        for name in names + [d for d in dirs if (Path(folder) / d).is_symlink()]:
            path = Path(folder) / name
            relative = path.relative_to(sweep_dir).as_posix()
            if relative not in own:
                out[relative] = path
    return out


def _mac(secret: bytes, relative: str, path: Path) -> str:
    digest = hmac.new(secret, relative.encode() + b"\0", hashlib.sha256)
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def sign(sweep_dir: Path, own: frozenset[str]) -> None:
    """Sign what Ray left in `sweep_dir` (its regular files; lab's `own` ones are data)."""
    secret = key()
    macs = {relative: _mac(secret, relative, path)
            for relative, path in sorted(_entries(sweep_dir, own).items())
            if path.is_file() and not path.is_symlink()}
    files.write_atomic(sweep_dir / SIGNATURE, json.dumps(macs, indent=1) + "\n",
                       below=sweep_dir)


def verify(sweep_dir: Path, own: frozenset[str]) -> None:
    """A LabError unless every entry Ray would read in `sweep_dir` is a regular file signed
    with the user's key as it is now, and every signed file is there."""
    refuse = "resume only sweeps your own lab sweep wrote; start this one again under a new --name"
    try:
        signed = json.loads(files.read_text(sweep_dir / SIGNATURE))
    except (files.Unreadable, ValueError):
        raise LabError(f"{sweep_dir}'s Ray Tune state carries no signature of yours (lab signs "
                       "it when a sweep stops; a sweep killed outright is left unsigned)",
                       refuse) from None
    if not isinstance(signed, dict):
        raise LabError(f"{sweep_dir / SIGNATURE} is damaged", refuse)
    secret = key()
    present = _entries(sweep_dir, own | {SIGNATURE})
    for relative, path in sorted(present.items()):
        mac = signed.get(relative)
        if (not isinstance(mac, str) or path.is_symlink() or not path.is_file()
                or not hmac.compare_digest(mac, _mac(secret, relative, path))):
            raise LabError(f"{path} is not Ray Tune state your lab sweep signed (added or "
                           "changed since): resuming would unpickle it", refuse)
    missing = sorted(set(signed) - set(present))
    if missing:
        raise LabError(f"{sweep_dir / missing[0]} is gone from the sweep's signed state",
                       refuse)
