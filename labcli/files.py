"""Writing files a user relies on: atomic (a temporary name, then a rename: a reader never sees half
a file, a kill leaves the previous one), durable (the file and its directory are fsynced before
the write counts), with the user's umask (as `open()` would create it), and never through a link:
a run dir may come from anyone, and a link planted in it must not send a write elsewhere."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from labcli.errors import LabError


def _umask() -> int:
    mask = os.umask(0o022)  # the only way to read it is to set it
    os.umask(mask)
    return mask


# Read once: a file created by mkstemp is 0600 whatever the umask, so lab sets the mode `open()`
# would have given it.
FILE_MODE = 0o666 & ~_umask()
DIR_MODE = 0o777 & ~_umask()


def fsync_dir(directory: Path) -> None:
    """Make a rename or a new file in `directory` durable (a power loss keeps it)."""
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def real_dir(path: Path, create: bool = True, below: Path | None = None) -> Path:
    """`path` as a directory that is no link (created, with its missing parents, when `create`):
    a link in a shared run dir would send lab's writes wherever it points. With `below`, every
    directory between `below` and `path` is checked so, not only `path`."""
    if below is not None and path != below:
        real_dir(path.parent, create, below)
    if path.is_symlink():
        raise LabError(f"{path} is a symbolic link; lab does not write through links in a run "
                       "dir", f"remove the link ({path}) and run again")
    if not path.exists():
        if not create:
            raise LabError(f"{path} does not exist")
        try:
            path.mkdir(parents=True, mode=DIR_MODE)
        except FileExistsError:  # made meanwhile by another process: checked again below
            pass
        except OSError as exc:
            raise unwritable(path, exc) from exc
    if path.is_symlink() or not path.is_dir():
        raise LabError(f"{path} is not a directory", "remove or rename it, then run again")
    return path


def unwritable(path: Path, exc: OSError) -> LabError:
    """The one line for a write that the file system refused (read-only, no space, no such
    directory, not permitted)."""
    reason = exc.strerror or type(exc).__name__
    return LabError(f"cannot write {path}: {reason}",
                    "free some space" if exc.errno == 28 else "pick a writable place")


def user_dir(path: Path) -> Path:
    """A directory the user named (`-o`): created if missing, links followed as the user meant."""
    try:
        path.mkdir(parents=True, exist_ok=True, mode=DIR_MODE)
    except OSError as exc:
        raise unwritable(path, exc) from exc
    return path


@contextlib.contextmanager
def staged(target: Path, below: Path | None = None) -> Iterator[Path]:
    """A fresh temporary path beside `target` (same suffix, so that libraries that look at it are
    content), created exclusively; renamed over `target` when the block ends, removed if it
    raises. Renaming replaces a link at `target` instead of following it. With `below` (a run
    dir), no directory between it and `target` may be a link; without, `target`'s directory is
    the user's, links and all."""
    directory = (user_dir(target.parent) if below is None
                 else real_dir(target.parent, below=below))
    try:
        fd, name = tempfile.mkstemp(dir=directory, prefix=f".tmp_{target.stem}.",
                                    suffix=target.suffix)
    except OSError as exc:
        raise unwritable(target, exc) from exc
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, FILE_MODE)
        fsync_file(tmp)
        os.replace(tmp, target)
        fsync_dir(directory)
    except OSError as exc:
        raise unwritable(target, exc) from exc
    finally:
        tmp.unlink(missing_ok=True)


def write_atomic(path: Path, data: str | bytes, below: Path | None = None) -> None:
    """Write `data` to `path` atomically and durably, with the user's umask (`below`: as in
    `staged`)."""
    with staged(path, below) as tmp:
        if isinstance(data, str):
            tmp.write_text(data)
        else:
            tmp.write_bytes(data)


def remove(path: Path) -> None:
    """Remove a file, a directory tree or a link, following no link."""
    if path.is_symlink() or path.is_file():
        path.unlink(missing_ok=True)
    elif path.is_dir():
        shutil.rmtree(path, ignore_errors=True)
