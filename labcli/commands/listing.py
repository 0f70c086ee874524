"""`lab list`."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from labcli.commands.common import out, table

if TYPE_CHECKING:
    from rich.text import Text


def list_() -> None:
    """List tasks (with their model), frameworks and wrappers, with the package that provides
    each.

    Example: lab list
    """
    from importlib.metadata import version

    from rich.table import Column

    from labcli.envs import gym_spec
    from labcli.plugins import registry

    reg = registry.loaded()
    for kind, title in ((registry.TASK, "Tasks"), (registry.FRAMEWORK, "Frameworks"),
                        (registry.WRAPPER, "Wrappers")):
        tasks = kind == registry.TASK
        # A task's model goes under its description: a column of its own squeezed the
        # descriptions of an 80-column terminal to a few words a line.
        rows = table(Column("name", no_wrap=True), "description",
                     Column("provided by", no_wrap=True), title=title)
        for name in reg.names(kind):
            item, provider = reg.items[kind][name]
            rows.add_row(name, _described(item.description, _model(item.model)) if tasks
                         else item.description, str(provider))
        if tasks:
            rows.add_row(f"{gym_spec.PREFIX}<id>",
                         _described(gym_spec.DESCRIPTION, "gymnasium's"),
                         f"gymnasium {version('gymnasium')}")
        out().print(rows)
    failures = [*reg.failures, *reg.unloadable()]
    if failures:
        rows = table("plugin", "package", "error", title="Plugins that failed to load")
        for failure in failures:
            rows.add_row(failure.plugin, str(failure.provider), failure.error)
        out().print(rows)


def _described(description: str, model: str) -> Text:
    from rich.text import Text

    return Text.assemble(description, "\n", (f"model: {model}", "dim"))


def _model(model: object) -> str:
    """A task's model in a few words: a Menagerie robot and entry, or an MJCF file's name."""
    from labcli.envs.spec import Menagerie

    return str(model) if isinstance(model, Menagerie) else Path(str(model)).name
