"""`lab list`."""

from __future__ import annotations

from pathlib import Path

from labcli.commands.common import out, table


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
        model = (Column("model", no_wrap=True),) if tasks else ()
        rows = table("name", "description", *model, "provided by", title=title)
        for name in reg.names(kind):
            item, provider = reg.items[kind][name]
            rows.add_row(name, item.description, *((_model(item.model),) if tasks else ()),
                         str(provider))
        if tasks:
            rows.add_row(f"{gym_spec.PREFIX}<id>", gym_spec.DESCRIPTION, "gymnasium's",
                         f"gymnasium {version('gymnasium')}")
        out().print(rows)
    failures = [*reg.failures, *reg.unloadable()]
    if failures:
        rows = table("plugin", "package", "error", title="Plugins that failed to load")
        for failure in failures:
            rows.add_row(failure.plugin, str(failure.provider), failure.error)
        out().print(rows)


def _model(model: object) -> str:
    """A task's model in a few words: a Menagerie robot and entry, or an MJCF file's name."""
    from labcli.envs.spec import Menagerie

    return str(model) if isinstance(model, Menagerie) else Path(str(model)).name
