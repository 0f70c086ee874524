"""Fixtures shared by the test modules."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

# labcli settles MUJOCO_GL on import (egl without a display), and MuJoCo reads it once, on its own
# first import: import labcli before any test module imports mujoco, so rendering tests see it.
from labcli.plugins import registry


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
