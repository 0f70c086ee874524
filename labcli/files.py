"""Reading and writing the files of a run dir, which may come from anyone.

Writes are atomic (a temporary name, then a rename: a reader never sees half a file, a kill leaves
the previous one), durable (the file and its directory are fsynced before the write counts), with
the user's umask (as `open()` would create it), and never through a link planted in a run dir.
Reads take regular files only, of bounded size, without blocking (a FIFO, /dev/zero), and YAML
and JSON are parsed with their nesting and YAML's alias expansion bounded."""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

from labcli.errors import LabError

TEXT_LIMIT = 16 << 20  # params, manifests, summaries, configs: far beyond any real one
# Nodes a YAML document may expand to (aliases counted each time they are used): a config has
# hundreds; a "billion laughs" document expands to 10^9 and exhausts memory when merged.
YAML_NODE_LIMIT = 100_000


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


def deleted(path: Path) -> LabError:
    return LabError(f"{path} no longer exists: it was deleted or moved while lab used it",
                    "nothing more was written")


def deletion(exc: BaseException, root: Path) -> LabError | None:
    """The one-line error for `exc` when it is a library's own write into `root` (TensorBoard's
    event file, written by SB3's logger) that found its directory deleted under lab; None for
    any other error."""
    filename = getattr(exc, "filename", None)
    if not isinstance(exc, FileNotFoundError) or filename is None:
        return None
    path = Path(os.fsdecode(filename))
    return deleted(vanished(path, root)) if path.is_relative_to(root) else None


def vanished(path: Path, root: Path) -> Path:
    """The outermost directory from `root` down to `path`'s that no longer exists (`path`'s own
    directory when all still do): what a deletion under lab took away. `rm -rf` of a run dir
    empties it from the inside, so its subdirectories go first."""
    directory = root
    for part in path.parent.relative_to(root).parts:
        if not directory.is_dir():
            return directory
        directory = directory / part
    return directory


def _failure(path: Path, exc: OSError, root: Path | None) -> LabError:
    """A write inside a run dir (`root`) that found a directory missing was undone under lab:
    lab made every directory it writes into just before."""
    if root is not None and (isinstance(exc, FileNotFoundError) or not root.is_dir()):
        return deleted(vanished(path, root))
    return unwritable(path, exc)


def real_dir(path: Path, create: bool = True, below: Path | None = None) -> Path:
    """`path` as a directory that is no link (created, with its missing parents, when `create`):
    a link in a shared run dir would send lab's writes wherever it points. With `below`, every
    directory between `below` and `path` is checked so, not only `path`."""
    if below is not None and path == below:
        if not path.is_dir():  # a run dir is never re-created: lab would leave a husk
            raise deleted(path)
        return path
    if below is not None:
        real_dir(path.parent, create, below)
    if path.is_symlink():
        raise LabError(f"{path} is a symbolic link; lab does not write through links in a run "
                       "dir", f"remove the link ({path}) and run again")
    if not path.exists():
        if not create:
            raise LabError(f"{path} does not exist")
        try:
            # Below a run dir its parents were made just above: a parent gone since was deleted
            # under lab, and is said so, not made again.
            path.mkdir(parents=below is None, mode=DIR_MODE)
        except FileExistsError:  # made meanwhile by another process: checked again below
            pass
        except OSError as exc:
            raise _failure(path, exc, below) from exc
    if path.is_symlink() or not path.is_dir():
        raise LabError(f"{path} is not a directory", "remove or rename it, then run again")
    return path


def unwritable(path: Path, exc: OSError) -> LabError:
    """The one line for a write that the file system refused (read-only, no space, no such
    directory, not permitted)."""
    reason = exc.strerror or type(exc).__name__
    return LabError(f"cannot write {path}: {reason}",
                    "free some space" if exc.errno == errno.ENOSPC else "pick a writable place")


# Less than this free after a failed write: the disk was full, whatever the writer said.
FULL_BELOW = 1 << 20


def failed_write(path: Path, exc: Exception, root: Path | None = None) -> LabError | None:
    """The one line for a write that failed, or None when it is no file-system failure: an
    OSError, or an error from a library that hides ENOSPC in its own (torch.save's "unexpected
    pos") while the disk is full. With `root` (a run dir): its disappearance, or that of a
    directory in it, is said as such."""
    if isinstance(exc, OSError):
        return _failure(path, exc, root)
    if root is not None and not root.is_dir():
        return deleted(root)
    try:
        full = shutil.disk_usage(path.parent).free < FULL_BELOW
    except OSError:
        return None
    return unwritable(path, OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))) if full else None


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
        raise _failure(target, exc, below) from exc
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, FILE_MODE)
        fsync_file(tmp)
        os.replace(tmp, target)
        fsync_dir(directory)
    except OSError as exc:
        raise _failure(target, exc, below) from exc
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


def sha256(path: Path) -> str:
    """The hex sha256 of the file at `path`, read in blocks."""
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def is_regular(path: Path) -> bool:
    """Whether `path` is a regular file (links followed), without opening it."""
    try:
        return stat.S_ISREG(path.stat().st_mode)
    except OSError:
        return False


class Unreadable(Exception):
    """A file lab will not read: not a regular file, too large, not valid text or data. The
    message is a predicate ("is not a regular file"), for the line `f"{path} {exc}"`."""


class TooLarge(Unreadable):
    """Data past lab's bounds: more bytes, nesting or YAML expansion than any real file has."""


def read_bytes(path: Path, limit: int = TEXT_LIMIT) -> bytes:
    """The content of the regular file at `path` (links followed), at most `limit` bytes. Opened
    without blocking, so that a FIFO cannot hang lab; a device, a directory or a larger file is
    refused before it is read."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise Unreadable(f"cannot be opened: {exc.strerror or type(exc).__name__}") from exc
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise Unreadable("is not a regular file")
        if info.st_size > limit:
            raise TooLarge(f"is {info.st_size:,} bytes, more than the {limit:,} lab reads")
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, min(1 << 20, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > limit:
            raise TooLarge(f"is more than the {limit:,} bytes lab reads")
        return b"".join(chunks)
    except OSError as exc:
        raise Unreadable(f"cannot be read: {exc.strerror or type(exc).__name__}") from exc
    finally:
        os.close(fd)


def read_text(path: Path, limit: int = TEXT_LIMIT) -> str:
    try:
        return read_bytes(path, limit).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise Unreadable(f"is not UTF-8 text (byte {exc.start})") from None


def load_yaml(text: str) -> Any:
    """YAML's safe loader, with nesting and alias expansion bounded (`YAML_NODE_LIMIT`)."""
    loader = None
    try:
        loader = yaml.SafeLoader(text)  # its reader refuses control characters at once
        node = loader.get_single_node()
        if node is None:
            return None
        _check_yaml_size(node)
        return loader.construct_document(node)
    except RecursionError:
        raise TooLarge("is YAML nested too deep") from None
    except yaml.YAMLError as exc:
        raise Unreadable(f"is not valid YAML: {str(exc).splitlines()[0]}") from None
    finally:
        if loader is not None:
            loader.dispose()


def _check_yaml_size(root: yaml.Node) -> None:
    """Count the nodes the document expands to, each alias as often as it is used, by a walk
    that sizes each distinct node once."""
    sizes: dict[int, int] = {}
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        if id(node) in sizes:
            continue
        children = _children(node)
        if children_done or not children:
            sizes[id(node)] = 1 + sum(sizes[id(c)] for c in children)
            if sizes[id(node)] > YAML_NODE_LIMIT:
                raise TooLarge(f"is YAML that expands to more than {YAML_NODE_LIMIT:,} nodes "
                                 "(aliases counted as often as they are used)")
            continue
        stack.append((node, True))
        stack.extend((c, False) for c in children if id(c) not in sizes)


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def load_json(data: bytes | str) -> Any:
    try:
        return json.loads(data)
    except RecursionError:
        raise TooLarge("is JSON nested too deep") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise Unreadable(f"is not valid JSON: {exc}") from None
