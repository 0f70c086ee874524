"""`lab list`."""

from __future__ import annotations

from labcli.commands.common import out, table


def list_() -> None:
    """List tasks, frameworks and wrappers, with the package that provides each.

    Example: lab list
    """
    from importlib.metadata import version

    from labcli.envs import gym_spec
    from labcli.plugins import registry

    reg = registry.loaded()
    for kind, title in ((registry.TASK, "Tasks"), (registry.FRAMEWORK, "Frameworks"),
                        (registry.WRAPPER, "Wrappers")):
        rows = table("name", "description", "provided by", title=title)
        for name in reg.names(kind):
            item, provider = reg.items[kind][name]
            rows.add_row(name, item.description, str(provider))
        if kind == registry.TASK:
            rows.add_row(f"{gym_spec.PREFIX}<id>", gym_spec.DESCRIPTION,
                         f"gymnasium {version('gymnasium')}")
        out().print(rows)
    failures = [*reg.failures, *reg.unloadable()]
    if failures:
        rows = table("plugin", "package", "error", title="Plugins that failed to load")
        for failure in failures:
            rows.add_row(failure.plugin, str(failure.provider), failure.error)
        out().print(rows)
