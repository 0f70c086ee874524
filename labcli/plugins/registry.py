"""Plugin discovery: every entry point of group "lab" is a plugin module, built-ins included.

Plugin modules register specs (tasks, frameworks, wrappers) whose heavy classes are named by
"module:Class" references: loading every plugin imports no learning library and no torch."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, entry_points, version
from typing import Any

import pluggy

from labcli import refs
from labcli.envs.gym_spec import is_gym_task
from labcli.envs.spec import TaskSpec
from labcli.envs.wrappers import WrapperSpec
from labcli.errors import LabError, first_line, unknown_name
from labcli.plugins import hookspecs
from labcli.plugins.framework import FrameworkSpec

GROUP = "lab"
TASK, FRAMEWORK, WRAPPER = "task", "framework", "wrapper"
KINDS = {TASK: "register_tasks", FRAMEWORK: "register_frameworks", WRAPPER: "register_wrappers"}
# What each hook must register: anything else is the plugin's error, reported, not fatal.
EXPECTED = {TASK: TaskSpec, FRAMEWORK: FrameworkSpec, WRAPPER: WrapperSpec}

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

    def unloadable(self) -> list[PluginFailure]:
        """Registered specs whose lazily named modules cannot be found: found without importing
        them, so `lab list` can say what would fail before anyone trains with it."""
        found = []
        for kind in (TASK, FRAMEWORK):
            for name, (spec, provider) in self.items[kind].items():
                for ref in spec.lazy_refs():
                    problem = refs.missing_module(ref)
                    if problem:
                        found.append(PluginFailure(provider.plugin, provider,
                                                   f"{kind} '{name}': {problem}"))
                        break
        return found


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
    return f"{type(exc).__name__}: {first_line(exc)}".rstrip(": ")


def _provider_of(plugin_name: str) -> Provider:
    return _dists.get(plugin_name, Provider(plugin_name, plugin_name, "(not installed)"))


@functools.cache
def loaded() -> Registry:
    """Load every plugin once and collect what each registers, attributed to its distribution.
    A framework's own wrappers are registered with it."""
    reg = Registry()
    _load_entry_points(reg.failures)
    for kind, hook_name in KINDS.items():
        for impl in getattr(pm.hook, hook_name).get_hookimpls():
            plugin_name = pm.get_name(impl.plugin)
            provider = _provider_of(plugin_name)
            found: list[Any] = []
            try:
                impl.function(register=found.append)
                for item in found:
                    if not isinstance(item, EXPECTED[kind]):
                        raise TypeError(f"{hook_name} registered a {type(item).__name__}, not a "
                                        f"{EXPECTED[kind].__name__} (see docs/plugins.md)")
            except Exception as exc:
                reg.failures.append(PluginFailure(plugin_name, provider, _one_line(exc)))
                continue
            for item in found:
                _add(reg, kind, item, provider)
                for wrapper in getattr(item, "wrappers", ()) if kind == FRAMEWORK else ():
                    _add(reg, WRAPPER, wrapper, provider)
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
    loaded.cache_clear()
    return loaded()


def get_task(name: str) -> Any:
    """A registered task's spec, or `gym:<id>`: any gymnasium env, made on demand."""
    if is_gym_task(name):
        from labcli.envs.gym_spec import task_spec

        return task_spec(name)
    return loaded().get(TASK, name)


def installed(dist: str) -> str | None:
    """The installed version of distribution `dist`, or None."""
    try:
        return version(dist)
    except PackageNotFoundError:
        return None


def get_framework(name: str) -> FrameworkSpec:
    return loaded().get(FRAMEWORK, name)


def get_wrapper(name: str) -> WrapperSpec:
    return loaded().get(WRAPPER, name)
