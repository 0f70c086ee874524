"""The reference of every term a robot task's config may hold (`labcli.envs.mdp.config`),
generated from the configs themselves: each term's kind, what it computes, and its settings
with their types, defaults and descriptions, as `--set env.<group>.<term>.<key>=VALUE` sets
them. docs/terms.md is its output, and a test keeps the two the same:

    python -m labcli.envs.mdp.reference > docs/terms.md
"""

from __future__ import annotations

import importlib
import inspect
import re
import sys
from typing import Any

from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from labcli.envs.mdp import config as c

# Each kind of term by its base class, in the order a task's config holds its groups.
KINDS = [
    ("Actions", c.ActionTerm, "env.actions"),
    ("Commands", None, "env.commands.<term>"),
    ("Observations", c.ObsTerm, "env.observations.<term>"),
    ("Rewards", c.RewardTerm, "env.rewards.<term>"),
    ("Terminations", c.TerminationTerm, "env.terminations.<term>"),
    ("Events", c.EventTerm, "env.events.<term>"),
    ("Curriculum", c.CurriculumTerm, "env.curriculum.<term>"),
    ("Success", None, "env.success"),
]
COMMAND_MODULE = "labcli.envs.mdp.commands"


def _terms() -> list[type[c.Term]]:
    """Every term class with code of its own, in the order config.py defines them."""
    found = [cls for _, cls in inspect.getmembers(c, inspect.isclass)
             if issubclass(cls, c.Term) and isinstance(getattr(cls, "impl", None), str)
             and cls.__module__ == c.__name__]
    return sorted(found, key=lambda cls: inspect.getsourcelines(cls)[1])


def kind_of(cls: type[c.Term]) -> str:
    for kind, base, _ in KINDS:
        if base is not None and issubclass(cls, base):
            return kind
    return "Commands" if cls.impl.startswith(COMMAND_MODULE) else "Success"


def _doc(cls: type[c.Term]) -> str:
    """The class's own docstring, else its code's (the function or class `impl` names)."""
    doc = vars(cls).get("__doc__")
    if not doc:
        module, _, name = cls.impl.partition(":")
        doc = inspect.getdoc(getattr(importlib.import_module(module), name)) or ""
    return " ".join(inspect.cleandoc(doc).split())


def _type(annotation: Any) -> str:
    text = getattr(annotation, "__name__", None) if isinstance(annotation, type) else None
    text = text or str(annotation)
    text = re.sub(r"\b(typing|labcli\.envs\.mdp\.[a-z_.]+)\.", "", text)
    return text.replace("NoneType", "None").replace("|", "\\|")


BOUNDS = {"gt": ">", "ge": "≥", "lt": "<", "le": "≤", "min_length": "length ≥",
          "max_length": "length ≤"}


def _bounds(field: FieldInfo) -> str:
    """The field's constraints, as "≥ 0, ≤ 1"."""
    said = [f"{sign} {getattr(item, key):g}" for item in field.metadata
            for key, sign in BOUNDS.items() if getattr(item, key, None) is not None]
    return f" ({', '.join(said)})" if said else ""


def _default(field: FieldInfo) -> str:
    if field.default_factory is not None:
        return "(built)"
    if field.default is PydanticUndefined:
        return "required"
    text = repr(field.default)
    return f"`{text}`" if len(text) <= 40 else f"`{text[:37]}...`"


def _settings(cls: type[c.Term]) -> list[str]:
    if not cls.model_fields:
        return ["No settings."]
    rows = ["| setting | type | default | meaning |", "| --- | --- | --- | --- |"]
    for name, field in cls.model_fields.items():
        meaning = " ".join((field.description or "").split()).replace("|", "\\|")
        rows.append(f"| `{name}` | {_type(field.annotation)}{_bounds(field)} | {_default(field)} "
                    f"| {meaning} |")
    return rows


def markdown() -> str:
    terms = _terms()
    lines = [
        "# Terms",
        "",
        "Every term a robot task's config may hold, by kind: what it computes and its settings,",
        "as `--set env.<group>.<term>.<key>=VALUE` sets them (`null` leaves a term out). Generated",
        "from `labcli/envs/mdp/config.py` by `python -m labcli.envs.mdp.reference`; `lab config",
        "show --task T` shows a task's own terms with their values.",
    ]
    for kind, base, where in KINDS:
        members = [cls for cls in terms if kind_of(cls) == kind]
        if not members:
            continue
        intro = " ".join(inspect.cleandoc(vars(base).get("__doc__") or "").split()) if base else ""
        lines += ["", f"## {kind}", "", f"Set under `{where}`. {intro}".rstrip(), ""]
        for cls in members:
            lines += [f"### {cls.__name__}", "", _doc(cls) or "(no description)", "",
                      *_settings(cls), ""]
        lines.pop()
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.stdout.write(markdown())
