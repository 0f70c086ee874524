"""Plugin discovery: every entry point of group "lab" is a plugin module, built-ins included."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any

import pluggy

from labcli import gym_bridge, hookspecs
from labcli.errors import LabError, unknown_name

GROUP = "lab"
KINDS = {
    "task": "register_tasks", "framework": "register_frameworks", "wrapper": "register_wrappers",
}

pm = pluggy.PluginManager(GROUP)
pm.add_hookspecs(hookspecs)


@dataclass(frozen=True)
class Provider:
    """Where a registered thing comes from: plugin name and its distribution."""

    plugin: str
    dist: str
    version: str

    def __str__(self) -> str:
        return f"{self.dist} {self.version}"


@dataclass
class PluginFailure:
    plugin: str
    provider: Provider
    error: str


@dataclass
class Registry:
    """Everything the loaded plugins registered, keyed by kind then name."""

    items: dict[str, dict[str, tuple[Any, Provider]]] = field(
        default_factory=lambda: {kind: {} for kind in KINDS}
    )
    failures: list[PluginFailure] = field(default_factory=list)

    def get(self, kind: str, name: str) -> Any:
        if name in self.items[kind]:
            return self.items[kind][name][0]
        error = unknown_name(kind, name, self.items[kind])
        if self.failures:
            broken = "; ".join(f"'{f.plugin}' from {f.provider}: {f.error}" for f in self.failures)
            error.hint += f"; plugins that failed to load, which may provide it: {broken}"
        raise error

    def names(self, kind: str) -> list[str]:
        return sorted(self.items[kind])

    def provider(self, kind: str, name: str) -> Provider:
        return self.items[kind][name][1]


def _load_entry_points(failures: list[PluginFailure]) -> None:
    for ep in entry_points(group=GROUP):
        dist = ep.dist.name if ep.dist else "?"
        version = ep.dist.version if ep.dist else "?"
        provider = Provider(ep.name, dist, version)
        if pm.has_plugin(ep.name):
            loaded = _dists.get(ep.name)
            if loaded is not None and loaded.dist != dist:
                failures.append(PluginFailure(ep.name, provider, (
                    f"entry point name '{ep.name}' is already taken by {loaded.dist}; "
                    "rename one of the two")))
            continue
        try:
            pm.register(ep.load(), name=ep.name)
        except Exception as exc:  # a broken third-party plugin must not break the others
            failures.append(PluginFailure(ep.name, provider, _one_line(exc)))
            continue
        _dists[ep.name] = provider


_dists: dict[str, Provider] = {}


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


def _provider_of(plugin_name: str) -> Provider:
    return _dists.get(plugin_name, Provider(plugin_name, plugin_name, "(not installed)"))


@functools.cache
def registry() -> Registry:
    """Load every plugin once and collect what each registers, attributed to its distribution."""
    reg = Registry()
    _load_entry_points(reg.failures)
    for kind, hook_name in KINDS.items():
        for impl in getattr(pm.hook, hook_name).get_hookimpls():
            plugin_name = pm.get_name(impl.plugin)
            provider = _provider_of(plugin_name)
            found: list[Any] = []
            try:
                impl.function(register=found.append)
            except Exception as exc:
                reg.failures.append(PluginFailure(plugin_name, provider, _one_line(exc)))
                continue
            for item in found:
                _add(reg, kind, item, provider)
    return reg


def _add(reg: Registry, kind: str, item: Any, provider: Provider) -> None:
    name = item.name
    if name in reg.items[kind]:
        other = reg.items[kind][name][1]
        raise LabError(
            f"{kind} '{name}' is registered twice: by {other.dist} (plugin '{other.plugin}') "
            f"and by {provider.dist} (plugin '{provider.plugin}')",
            "uninstall one of the two packages",
        )
    reg.items[kind][name] = (item, provider)


def reload() -> Registry:
    """Forget what was loaded (tests register and unregister plugins) and load again."""
    registry.cache_clear()
    return registry()


def get_task(name: str):
    """A registered task, or `gym:<id>`: any gymnasium env, made on demand."""
    if gym_bridge.is_gym_task(name):
        return gym_bridge.task_spec(name)
    return registry().get("task", name)


def get_framework(name: str):
    return registry().get("framework", name)


def get_wrapper(name: str):
    return registry().get("wrapper", name)
