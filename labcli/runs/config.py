"""Resolve env and agent configs: defaults ← task's per-framework defaults ← file ← --set."""

from __future__ import annotations

import copy
import difflib
import os
import shlex
import types
import typing
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from labcli import files
from labcli.envs.config import TaskConfig
from labcli.envs.spec import TaskSpec
from labcli.errors import LabError, one_line
from labcli.plugins.config import AgentConfig
from labcli.plugins.framework import FrameworkSpec

SECTIONS = ("env", "agent")


def parse_set(items: Iterable[str]) -> dict[str, dict[str, Any]]:
    """`["env.num_envs=8", "agent.learning_rate=3e-4"]` → nested dicts per section. Values are
    read as YAML (numbers, booleans, lists); pydantic then checks them against the models."""
    out: dict[str, dict[str, Any]] = {s: {} for s in SECTIONS}
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        section, _, path = key.partition(".")
        if not sep or section not in SECTIONS or not path:
            raise LabError(f"--set '{item}' is not SECTION.KEY=VALUE",
                           "e.g. --set agent.learning_rate=3e-4 or --set env.num_envs=32")
        try:
            value = files.load_yaml(raw) if raw.strip() else ""
        except files.TooLarge as exc:
            raise LabError(f"--set {key}: the value {exc}") from None
        except Exception:  # not YAML (PyYAML raises more than YAMLError, e.g. ValueError for
            value = raw  # 2020-13-45): the string as written
        if value == {}:  # merged into what is there, it would change nothing
            raise LabError(f"--set {key}={{}} sets nothing: a mapping's keys are set one by one",
                           f"set a key below it (--set {key}.KEY=VALUE), or {key}=null to "
                           "leave a term out")
        _set_path(out[section], section, path.split("."), value)
    return out


def _set_path(tree: dict[str, Any], section: str, keys: list[str], value: Any) -> None:
    for depth, key in enumerate(keys[:-1]):
        tree = tree.setdefault(key, {})
        if not isinstance(tree, dict):
            parent = ".".join([section, *keys[:depth + 1]])
            raise LabError(f"--set {parent} holds a value, so it has no key '{keys[depth + 1]}'",
                           f"set either {parent} or keys below it, not both")
    tree[keys[-1]] = value


def load_file(path: Path) -> dict[str, dict[str, Any]]:
    if not path.exists():
        raise LabError(f"config file {path} does not exist")
    try:
        data = files.load_yaml(files.read_text(path))
    except files.Unreadable as exc:
        raise LabError(f"config file {path} {exc}", "pass a YAML file") from None
    data = {} if data is None else data  # an empty file
    if not isinstance(data, dict) or set(data) - set(SECTIONS):
        raise LabError(f"config file {path} must be a mapping with keys 'env' and/or 'agent'")
    for section in SECTIONS:
        if not isinstance(data.get(section) or {}, dict):
            raise LabError(f"config file {path}: '{section}' holds {type(data[section]).__name__}"
                           f" {data[section]!r}, not settings", f"give '{section}:' a mapping "
                           "of KEY: VALUE, as `lab config show` writes it")
    return {s: data.get(s) or {} for s in SECTIONS}


def merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """Deep-merge `override` into a copy of `base`."""
    out = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def build(model: type[BaseModel], section: str, layers: Iterable[Mapping[str, Any]]) -> BaseModel:
    """Validate the merged `layers` as `model`; a bad key or value becomes one clear LabError."""
    data: dict[str, Any] = {}
    for layer in layers:
        data = merge(data, layer)
    # Dict-valued fields (reward weights) merge over their defaults rather than replace them.
    defaults = model().model_dump()
    for key, value in data.items():
        if isinstance(value, Mapping) and isinstance(defaults.get(key), dict):
            data[key] = merge(defaults[key], value)
    _reject_bools_as_numbers(model, data, section)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise _explain(exc, model, section) from None


def check_saved(model: type[BaseModel], section: str, path: Path, data: Mapping[str, Any],
                given: Sequence[Mapping[str, Any]] = ()) -> None:
    """Validate a run's saved params on their own, so that an error names the file (damaged or
    edited by hand) rather than a key the user never passed. The env's settings build the env,
    which opens the files they name (a gymnasium env's `kwargs.xml_file`): a run dir is data, so
    a value in them that names a file is refused, before any file is opened, unless `given`
    (this command's --config and --set layers of `section`) sets that key, and so the value the
    env gets is the user's, not the run dir's (docs/robustness.md, "Trust")."""
    try:
        build(model, section, [data])
    except LabError as exc:
        raise LabError(f"{path}: {exc.message}", exc.hint or "fix or restore the file") from None
    if section != "env":  # the agent's settings build networks, which open no file
        return
    for keys, value in named_files(data):
        if not any(_sets(layer, keys) for layer in given):
            named = settable(keys)
            assign = ".".join([section, *map(str, named)]) + (
                f"={value}" if named == keys else "=[...]")
            shown = repr(value) if len(repr(value)) <= 120 else f"{repr(value)[:117]}..."
            raise LabError(one_line(f"{path}: {'.'.join([section, *map(str, keys)])} names the "
                                    f"file {shown}, and lab opens no file that a run dir names"),
                           one_line(f"if you trust it, pass it yourself: --set "
                                    f"{shlex.quote(assign)}"))


# A string that names a path, not a bare name: one with a separator ("/etc/passwd", "./x.xml",
# "a/b"), from the home directory ("~", "~/x") or the working directory or its parent ("."
# alone, ".."). A bare name ("ant.xml") is not taken for one: gymnasium's MuJoCo envs read it
# from their own assets; nor is a pattern (".*_foot", "leg_\d": a backslash is no separator on
# POSIX).
def names_a_file(value: Any) -> bool:
    """Whether a setting's value names a file (or a directory) by its path."""
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if not isinstance(value, str):
        return False
    return (os.sep in value or bool(os.altsep and os.altsep in value)
            or value.lstrip().startswith("~") or value.strip() in (".", ".."))


# Settings that always name a file that lab opens from the working directory, a bare name too
# (a motor model's actuator net: `env.robot.actuators.<group>.network.file`).
FILE_KEYS = frozenset({"file"})


def named_files(data: Any, keys: tuple = ()) -> Iterable[tuple[tuple, Any]]:
    """Every value in `data` (nested mappings and lists) that names a file, with its keys."""
    if isinstance(data, Mapping):
        for key, value in data.items():
            yield from named_files(value, (*keys, key))
    elif isinstance(data, (list, tuple, set, frozenset)):
        for index, value in enumerate(data):
            yield from named_files(value, (*keys, index))
    elif names_a_file(data) or (keys and keys[-1] in FILE_KEYS and isinstance(data, str)):
        yield keys, data


def _sets(layer: Any, keys: tuple) -> bool:
    """Whether merging `layer` over saved settings replaces the value at `keys` (`merge`: a
    mapping merges into a mapping, anything else replaces what was there)."""
    for key in keys:
        if not isinstance(layer, Mapping):
            return True  # set at a key above: what was below is gone
        if key not in layer:
            return False
        layer = layer[key]
    return True


def settable(keys: tuple) -> tuple:
    """The keys down to the first list index: what `--set` can name."""
    for i, key in enumerate(keys):
        if isinstance(key, int):
            return keys[:i]
    return keys


def _reject_bools_as_numbers(model: type[BaseModel], data: Mapping[str, Any], section: str
                             ) -> None:
    """pydantic's lax mode reads `true` as 1 for a number (`--set env.num_envs=true` would run
    one env); strict mode would also refuse the string YAML makes of `3e-4`. So: lax, but no
    booleans where only numbers go."""
    for key, value in data.items():
        field = model.model_fields.get(key)
        found = _bool_in_number(field.annotation, value, [key]) if field else None
        if found is not None:
            path, annotation = found
            raise LabError(f"bad value for '{'.'.join([section, *map(str, path)])}': a boolean "
                           f"where a number is expected (got {_value_at(value, path[1:])!r})",
                           f"expected {_type_name(annotation)}")


def _bool_in_number(annotation: Any, value: Any, path: list) -> tuple[list, Any] | None:
    """The path to a bool inside `value` where `annotation` takes only numbers, and that
    number's type; None if there is none. Goes into nested models (a robot task's terms)."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:
        return _bool_in_number(args[0], value, path)
    if origin in (typing.Union, types.UnionType):
        numeric = [a for a in args if a is not type(None)]
        return _bool_in_number(numeric[0], value, path) if len(numeric) == 1 else None
    if isinstance(value, bool):
        return (path, annotation) if _numbers_only(annotation) else None
    if isinstance(value, Mapping) and isinstance(annotation, type) \
            and issubclass(annotation, BaseModel):
        for key, item in value.items():
            field = annotation.model_fields.get(key)
            found = _bool_in_number(field.annotation, item, [*path, key]) if field else None
            if found:
                return found
    if isinstance(value, (list, tuple)) and origin in (list, tuple, set, frozenset) and args:
        for i, item in enumerate(value):
            item_type = args[0] if origin is not tuple or args[-1] is Ellipsis else \
                args[min(i, len(args) - 1)]
            found = _bool_in_number(item_type, item, [*path, i])
            if found:
                return found
    if isinstance(value, Mapping) and origin is dict and len(args) == 2:
        for key, item in value.items():
            found = _bool_in_number(args[1], item, [*path, key])
            if found:
                return found
    return None


def _numbers_only(annotation: Any) -> bool:
    if typing.get_origin(annotation) is typing.Annotated:
        return _numbers_only(typing.get_args(annotation)[0])
    return annotation in (int, float)


def _value_at(value: Any, path: list) -> Any:
    for key in path:
        value = value[key]
    return value


def _explain(exc: ValidationError, model: type[BaseModel], section: str) -> LabError:
    err = exc.errors()[0]
    if not err["loc"]:  # about the settings together (a model validator), not one key
        message = err["msg"].removeprefix("Value error, ")
        return LabError(f"bad {section} settings: {message}",
                        f"see `lab config show` for the {section} settings")
    key = ".".join([section, *(str(p) for p in err["loc"])])
    if err["type"] == "extra_forbidden":
        fields = sorted(model.model_fields)
        close = difflib.get_close_matches(str(err["loc"][-1]), fields, n=1)
        hint = f"did you mean '{section}.{close[0]}'? " if close else ""
        return LabError(f"unknown key '{key}'",
                        hint + f"keys of {section}: {', '.join(fields)}")
    field = model.model_fields.get(str(err["loc"][0]))
    expected = _type_name(_annotation_at(field.annotation, len(err["loc"]) - 1)) if field \
        else "a valid value"
    return LabError(f"bad value for '{key}': {err['msg']} (got {err.get('input')!r})",
                    f"expected {expected}")


def _annotation_at(annotation: Any, depth: int) -> Any:
    """The type of an item `depth` levels inside a container field (dict value, list item)."""
    for _ in range(depth):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if not args:
            break
        annotation = args[-1]
    return annotation


def _type_name(annotation: Any) -> str:
    if typing.get_origin(annotation) is typing.Annotated:  # PositiveInt and the like
        return _type_name(typing.get_args(annotation)[0])
    if typing.get_origin(annotation) is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(annotation))
    return getattr(annotation, "__name__", None) or str(annotation).replace("typing.", "")


# The key, inside a task's defaults for a framework, of the settings for the GPU scale (the
# warp backend: thousands of envs, larger mini-batches), applied over the others there.
GPU_SCALE = "warp"


def resolve(spec: TaskSpec, fw: FrameworkSpec, *, base: tuple[dict, dict] | None = None,
            config_file: Path | None = None, overrides: Sequence[str] = (),
            num_envs: int | None = None, max_iterations: int | None = None,
            seed: int | None = None, gpu_scale: bool = False) -> tuple[TaskConfig, AgentConfig]:
    """defaults ← the framework's defaults for this task ← the task's defaults for this
    framework (with `gpu_scale`, each followed by its "warp" settings) ← `base` (a resumed run)
    ← file ← --set ← the explicit flags."""
    layers = []
    for defaults in (fw.task_defaults.get(spec.name, {}), spec.framework_defaults.get(fw.name, {})):
        for layer in (defaults, defaults.get(GPU_SCALE, {}) if gpu_scale else {}):
            layers.append({"env": dict(layer.get("env", {})),
                           "agent": dict(layer.get("agent", {}))})
    if base is not None:
        layers.append({"env": base[0], "agent": base[1]})
    if config_file is not None:
        layers.append(load_file(config_file))
    layers.append(parse_set(overrides))
    flags: dict[str, dict[str, Any]] = {"env": {}, "agent": {}}
    if num_envs is not None:
        flags["env"]["num_envs"] = num_envs
    if max_iterations is not None:
        flags["agent"]["max_iterations"] = max_iterations
    if seed is not None:
        flags["agent"]["seed"] = seed
    layers.append(flags)
    env_cfg = build(spec.config_class, "env", [layer["env"] for layer in layers])
    agent_cfg = build(fw.agent_config_class, "agent", [layer["agent"] for layer in layers])
    return env_cfg, agent_cfg


def changes(saved: BaseModel, now: BaseModel, section: str) -> dict[str, tuple[Any, Any]]:
    """The settings of `section` that differ between a run's saved config and the resolved one:
    {"agent.learning_rate": (old, new), ...}."""
    old, new = saved.model_dump(mode="json"), now.model_dump(mode="json")
    return {f"{section}.{key}": (old.get(key), value) for key, value in new.items()
            if old.get(key) != value}


def check_resumable(checkpoint: str, changed: Mapping[str, tuple[Any, Any]],
                    env_model: type[BaseModel], agent_model: type[BaseModel]) -> None:
    """Refuse, before anything is written, a resume that changes what its checkpoint holds."""
    allowed = {**{f"env.{k}": True for k in getattr(env_model, "resumable", ())},
               **{f"agent.{k}": True for k in getattr(agent_model, "resumable", ())}}
    refused = [key for key in changed if key not in allowed]
    if refused:
        key = refused[0]
        old, new = changed[key]
        also = f" (and {', '.join(refused[1:])})" if refused[1:] else ""
        raise LabError(f"resuming {checkpoint} cannot change {key} ({old!r} -> {new!r}){also}: "
                       "the checkpoint was trained with it",
                       f"a resume may change {', '.join(sorted(allowed))}; start a new run "
                       "(no --checkpoint) to change the others")


def to_yaml(model: BaseModel) -> str:
    return yaml.safe_dump(model.model_dump(mode="json"), sort_keys=False)


def dump(env: BaseModel, agent: BaseModel) -> str:
    """Both sections as one YAML document, the form `load_file` reads back."""
    return yaml.safe_dump({"env": env.model_dump(mode="json"),
                           "agent": agent.model_dump(mode="json")}, sort_keys=False)
