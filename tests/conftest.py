"""Fixtures shared by the test modules."""

from __future__ import annotations

import contextlib
import os
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

# labcli settles MUJOCO_GL on import (egl without a display), and MuJoCo reads it once, on its own
# first import: import labcli before any test module imports mujoco, so rendering tests see it.
from labcli.plugins import registry

# No internet in CI: Menagerie's robots come from the offline copy of their folders beside the
# project (../shared/menagerie), unpacked once, as .ci/run does, unless MENAGERIE_ROOT is set.
UNPACK = Path(__file__).resolve().parents[2] / "shared" / "menagerie" / "unpack"
if "MENAGERIE_ROOT" not in os.environ and UNPACK.is_file():
    os.environ["MENAGERIE_ROOT"] = subprocess.run(
        [str(UNPACK)], check=True, capture_output=True, text=True).stdout.strip()


# The test workers share the machine's cores: each training's update (and each `lab` the tests
# start) on one torch thread, as two trainings sharing a laptop should run (docs/frameworks.md).
os.environ.setdefault("OMP_NUM_THREADS", "1")


# The key that signs sweep state (labcli/runs/sweep_state.py) is the tests' own, not the
# user's: one per test session.
if "LAB_CONFIG_DIR" not in os.environ:
    import tempfile

    os.environ["LAB_CONFIG_DIR"] = tempfile.mkdtemp(prefix="lab-test-config-")


@contextlib.contextmanager
def no_device_waits(device: str) -> Iterator[None]:
    """Inside, an op that makes the host wait for the GPU raises a RuntimeError: on CUDA
    torch's sync debug mode (once the work queued before is done), on the CPU the ops of
    host_ops.DEVICE_WAITS as the dispatcher sees them."""
    import torch
    from host_ops import DEVICE_WAITS, HostOps

    if torch.device(device).type != "cuda":
        with HostOps(DEVICE_WAITS, raising=True):
            yield
        return
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        yield
    finally:
        torch.cuda.set_sync_debug_mode("default")


def needs_menagerie(robot: str) -> pytest.MarkDecorator:
    """Skips a test where Menagerie's `robot` is neither in MENAGERIE_ROOT nor in the cache."""
    import mujoco_menagerie as mm

    root = os.environ.get("MENAGERIE_ROOT")
    there = (Path(root) / robot).is_dir() if root else mm.Cache().is_cached(mm.get(robot))
    return pytest.mark.skipif(not there, reason=f"Menagerie's {robot} is not here (no internet: "
                              "export MENAGERIE_ROOT=$(../shared/menagerie/unpack))")


def needs_warp() -> pytest.MarkDecorator:
    """Skips a test where there is no CUDA GPU or MuJoCo Warp is not installed."""
    import importlib.util

    import torch

    there = all(importlib.util.find_spec(m) for m in ("warp", "mujoco_warp"))
    return pytest.mark.skipif(not (there and torch.cuda.is_available()),
                              reason='needs a CUDA GPU and MuJoCo Warp (pip install -e ".[warp]")')


@pytest.fixture
def register_plugin() -> Iterator[Callable[[object, str], None]]:
    """Registers plugin objects (a class instance or a module) under a name, then removes them."""
    names: list[str] = []

    def register(plugin: object, name: str) -> None:
        registry.pm.register(plugin, name=name)
        names.append(name)
        registry.reload()

    yield register
    for name in names:
        if registry.pm.has_plugin(name):
            registry.pm.unregister(name=name)
    registry.reload()
