"""Lazy references: a plugin names its heavy classes as "module:attribute" strings, as entry points
and gymnasium's registry do, so that listing what is installed imports no learning library."""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
from typing import Any

from labcli.errors import LabError, first_line


def resolve(ref: Any, what: str) -> Any:
    """`ref` itself, or the object a "module:attribute" string names, imported now. `what` says
    whose reference it is, for the error a missing module or attribute becomes."""
    if not isinstance(ref, str):
        return ref
    module_name, _, attribute = ref.partition(":")
    try:
        obj: Any = importlib.import_module(module_name)
        for name in filter(None, attribute.split(".")):
            obj = getattr(obj, name)
    except Exception as exc:  # an import error of the plugin's own code: one line, not a crash
        raise LabError(f"{what}: cannot load '{ref}' ({type(exc).__name__}: {first_line(exc)})",
                       "reinstall the plugin's package, or see `lab list` for what failed"
                       ) from None
    return obj


def missing_module(ref: Any) -> str | None:
    """Why the module of a "module:attribute" reference cannot be found, found without importing
    it or its parent packages (a library's __init__ may take seconds); None when it can be found,
    or `ref` is no string."""
    if not isinstance(ref, str):
        return None
    module_name = ref.partition(":")[0]
    top, *subs = module_name.split(".")
    try:
        found = importlib.util.find_spec(top)
        for depth, sub in enumerate(subs, start=1):
            if found is None or found.submodule_search_locations is None:
                break
            name = ".".join([top, *subs[:depth - 1], sub])
            found = importlib.machinery.PathFinder.find_spec(
                name, list(found.submodule_search_locations))
    except (ImportError, ValueError) as exc:
        return f"{type(exc).__name__}: {first_line(exc)}"
    return None if found is not None else f"no module named '{module_name}'"
