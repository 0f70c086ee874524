"""The records of an offline W&B run file (`run-<id>.wandb`, what `wandb sync` uploads): W&B's
protobuf `Record`s in the LevelDB log format, blocks of 32 KiB after a 7-byte file header, each
record a 7-byte header (crc32c, length, type) and a chunk (whole, or first/middle/last)."""

from __future__ import annotations

import struct
import time
from pathlib import Path

from google.protobuf.message import DecodeError
from wandb.proto import wandb_internal_pb2

BLOCK, HEADER = 32768, 7
FULL, FIRST, MIDDLE, LAST = 1, 2, 3, 4


def records(path: Path) -> list[wandb_internal_pb2.Record]:
    data = path.read_bytes()
    assert data[:4] == b":W&B", path
    pos, chunks, parts = HEADER, [], b""
    while pos + HEADER <= len(data):
        left = BLOCK - pos % BLOCK
        if left < HEADER:  # a block's tail too short for a header is padding
            pos += left
            continue
        _, length, kind = struct.unpack("<IHB", data[pos:pos + HEADER])
        chunk = data[pos + HEADER:pos + HEADER + length]
        pos += HEADER + length
        if kind == FULL:
            chunks.append(chunk)
        elif kind in (FIRST, MIDDLE):
            parts += chunk
        elif kind == LAST:
            chunks.append(parts + chunk)
            parts = b""
        else:  # zeros: the block's unused end
            break
    out = []
    for chunk in chunks:
        record = wandb_internal_pb2.Record()
        record.ParseFromString(chunk)
        out.append(record)
    return out


def finished(run_dir: Path, timeout_s: float = 30.0) -> Path:
    """The run file in an offline run's directory once it holds the run's exit record, its last:
    `run.finish()` returns before W&B's service process has written it all."""
    deadline = time.monotonic() + timeout_s
    while True:
        path = next(run_dir.glob("run-*.wandb"), None)
        try:
            if path and any(r.WhichOneof("record_type") == "exit" for r in records(path)):
                return path
        except (AssertionError, DecodeError):  # not yet its header, or a record half written
            pass
        if time.monotonic() > deadline:
            raise AssertionError(f"{run_dir} holds no finished run file after {timeout_s:g} s")
        time.sleep(0.05)


def of_type(path: Path, kind: str) -> list:
    """The records of one type ("run", "history", "artifact"...), as their own messages."""
    return [getattr(r, kind) for r in records(path) if r.WhichOneof("record_type") == kind]


def row(history) -> dict[str, str]:
    """A history record's figures, by key, as JSON text."""
    return {item.key or "/".join(item.nested_key): item.value_json for item in history.item}
