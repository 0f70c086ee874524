"""Fixtures shared by the test modules."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from labcli import plugins


@pytest.fixture
def register_plugin() -> Iterator[Callable[[object, str], None]]:
    """Registers plugin objects (a class instance or a module) under a name, then removes them."""
    names: list[str] = []

    def register(plugin: object, name: str) -> None:
        plugins.pm.register(plugin, name=name)
        names.append(name)
        plugins.reload()

    yield register
    for name in names:
        if plugins.pm.has_plugin(name):
            plugins.pm.unregister(name=name)
    plugins.reload()
