"""A sweep's search space: a YAML file mapping `env.*` / `agent.*` keys to one distribution
each, read and checked whole before any trial starts (no Ray here):

    agent.learning_rate: {loguniform: [1.0e-4, 1.0e-2]}
    agent.entropy_coef: {uniform: [0.0, 0.01]}
    agent.num_learning_epochs: {choice: [4, 8]}
    agent.num_mini_batches: {randint: [2, 8]}     # both ends included

Each key is checked as `lab train --set` checks it, with the sweep's fixed settings: the bounds
of a range, a point inside it and every choice must be values the task's or framework's config
takes, so that no trial fails on a value it drew."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from labcli import files
from labcli.errors import LabError
from labcli.runs import config

UNIFORM, LOGUNIFORM, RANDINT, CHOICE = "uniform", "loguniform", "randint", "choice"
DISTRIBUTIONS = (UNIFORM, LOGUNIFORM, RANDINT, CHOICE)
# Tune's randint draws with NumPy in int64, its upper end excluded (lab's high + 1).
INT64 = (-(2**63), 2**63 - 1)
EXAMPLE = "e.g. agent.learning_rate: {loguniform: [1.0e-4, 1.0e-2]}"
# Set by the sweep itself: the trials' length (--iterations, ASHA's horizon) and their physics
# threads (sized to the cores each trial gets).
RESERVED = {"agent.max_iterations": "set it with --iterations",
            "env.threads": "the sweep sizes it to the cores each trial gets; --set it to fix it"}
# YAML 1.1 (PyYAML) reads 1e-4 as a string, YAML 1.2 and every user as a number.
_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")
# A point strictly inside a range, at an irrational fraction of it: no integer for any bounds a
# space would have, so that a range over an integer key is refused.
_INSIDE = 1 / math.e


@dataclass(frozen=True)
class Distribution:
    kind: str  # one of DISTRIBUTIONS
    values: tuple[Any, ...]  # (low, high) for a range, the choices for `choice`

    def describe(self) -> str:
        return f"{self.kind} {list(self.values)}"

    def probes(self) -> list[Any]:
        """The values to check against the config: the ends and a point inside for a range
        (randint draws whole numbers only), every choice."""
        if self.kind == CHOICE:
            return list(self.values)
        low, high = self.values
        if self.kind == RANDINT:
            return [low, high]
        if self.kind == LOGUNIFORM:
            inside = math.exp(math.log(low) + _INSIDE * (math.log(high) - math.log(low)))
        else:
            inside = low + _INSIDE * (high - low)
        return [low, inside, high]


Space = dict[str, Distribution]


def load(path: Path) -> Space:
    """The distributions of the space file at `path`, each well formed (not yet checked against
    a task's config: `check` does that)."""
    if not path.exists():
        raise LabError(f"space file {path} does not exist", f"write one: {EXAMPLE}")
    try:
        data = files.load_yaml(files.read_text(path))
    except files.Unreadable as exc:
        raise LabError(f"space file {path} {exc}", f"write one: {EXAMPLE}") from None
    return parse(data, str(path))


def parse(data: Any, where: str = "the space") -> Space:
    if not isinstance(data, dict) or not data:
        raise LabError(f"{where} must map keys to distributions",
                       f"{EXAMPLE}; distributions: {', '.join(DISTRIBUTIONS)}")
    return {str(key): _distribution(str(key), value, where) for key, value in data.items()}


def _distribution(key: str, spec: Any, where: str) -> Distribution:
    section, _, name = key.partition(".")
    if section not in config.SECTIONS or not name:
        raise LabError(f"{where}: '{key}' is not an env.* or agent.* key",
                       f"e.g. agent.learning_rate or env.num_envs; {EXAMPLE}")
    if key in RESERVED:
        raise LabError(f"{where}: '{key}' cannot be swept", RESERVED[key])
    if not isinstance(spec, dict) or len(spec) != 1:
        raise LabError(f"{where}: '{key}' must be one distribution, as {{NAME: [ARGS]}}",
                       f"{EXAMPLE}; distributions: {', '.join(DISTRIBUTIONS)}")
    ((kind, args),) = spec.items()
    if kind not in DISTRIBUTIONS:
        hint = _close(str(kind))
        raise LabError(f"{where}: '{key}' has an unknown distribution '{kind}'",
                       f"{hint}distributions: {', '.join(DISTRIBUTIONS)}")
    if kind == CHOICE:
        if not isinstance(args, list) or not args:
            raise LabError(f"{where}: '{key}': choice needs a non-empty list of values",
                           f"e.g. {key}: {{choice: [4, 8]}}")
        return Distribution(CHOICE, tuple(_number_or_value(v) for v in args))
    if not isinstance(args, list) or len(args) != 2:
        raise LabError(f"{where}: '{key}': {kind} needs [low, high], got {args!r}",
                       f"e.g. {key}: {{{kind}: {_example(kind)}}}")
    low, high = (_number(key, kind, value, where) for value in args)
    if kind == RANDINT:
        if not (float(low).is_integer() and float(high).is_integer()):
            raise LabError(f"{where}: '{key}': randint needs whole numbers, got [{low}, {high}]",
                           "use uniform for a range of real numbers")
        low, high = int(low), int(high)
        if low > high:
            raise LabError(f"{where}: '{key}': randint's low {low} is above its high {high}",
                           f"write [low, high], e.g. [{high}, {low}]")
        if not (INT64[0] <= low and high < INT64[1]):
            raise LabError(f"{where}: '{key}': randint [{low}, {high}] leaves the 64-bit "
                           "integers Ray Tune draws from", "keep both ends within ±9.2e18")
    elif not low < high:
        raise LabError(f"{where}: '{key}': {kind}'s low {low} is not below its high {high}",
                       f"write [low, high], e.g. [{min(low, high)}, {max(low, high)}]; for one "
                       "value use --set or choice")
    if kind == LOGUNIFORM and low <= 0:
        raise LabError(f"{where}: '{key}': loguniform needs a positive low, got {low}",
                       "use uniform for a range that reaches 0 or below")
    return Distribution(kind, (low, high))


def _number(key: str, kind: str, value: Any, where: str) -> int | float:
    number = _number_or_value(value)
    if isinstance(number, bool) or not isinstance(number, (int, float)) \
            or not math.isfinite(number):
        raise LabError(f"{where}: '{key}': {kind}'s bounds must be finite numbers, got "
                       f"{value!r}", f"e.g. {key}: {{{kind}: {_example(kind)}}}")
    return number


def _number_or_value(value: Any) -> Any:
    if isinstance(value, str) and _NUMBER.fullmatch(value.strip()):
        number = float(value)
        return int(number) if re.fullmatch(r"[-+]?\d+", value.strip()) else number
    return value


def _example(kind: str) -> str:
    return {UNIFORM: "[0.0, 0.01]", LOGUNIFORM: "[1.0e-4, 1.0e-2]", RANDINT: "[2, 8]"}[kind]


def _close(kind: str) -> str:
    import difflib

    close = difflib.get_close_matches(kind, DISTRIBUTIONS, n=1, cutoff=0.7)
    return f"did you mean '{close[0]}'? " if close else ""


def check(space: Space, spec: Any, fw: Any, fixed: Sequence[str], *,
          max_iterations: int | None = None, gpu_scale: bool = False,
          where: str = "the space", scalar_choices: bool = False) -> None:
    """Each key of `space` must be a setting of the task (env.*) or the framework (agent.*),
    and every value it can draw must validate there with the `fixed` --set values, as
    `lab train --set` would check it. `scalar_choices`: Optuna draws among numbers, strings and
    booleans only."""
    fixed_keys = {item.partition("=")[0].strip() for item in fixed}
    for key, dist in space.items():
        if key in fixed_keys:
            raise LabError(f"{where}: '{key}' is both swept and fixed with --set",
                           "drop one of them")
        for value in dist.probes():
            if scalar_choices and not isinstance(value, (int, float, str, bool, type(None))):
                raise LabError(f"{where}: '{key}': --search optuna draws among numbers, "
                               f"strings and booleans, not {value!r}",
                               "use --search random for choices of lists or mappings")
            try:
                env_cfg, agent_cfg = config.resolve(
                    spec, fw, overrides=[*fixed, override(key, value)],
                    max_iterations=max_iterations, gpu_scale=gpu_scale)
                agent_cfg.check(env_cfg.num_envs)
            except LabError as exc:
                named = "" if f"'{key}'" in exc.message else f"'{key}': "
                if dist.kind in (UNIFORM, LOGUNIFORM) and value not in dist.values:
                    # Its ends passed: the key takes whole numbers only.
                    raise LabError(f"{where}: {named}{exc.message}, a value {dist.describe()} "
                                   "draws", f"{dist.kind} draws real numbers: use randint or "
                                   f"choice for {key}") from None
                raise LabError(f"{where}: {named}{exc.message}", exc.hint) from None


def override(key: str, value: Any) -> str:
    """`key=value` as `--set` takes it: the value written as YAML reads it back (1e-05 as a
    number, a list as a list)."""
    return f"{key}={dump_value(value)}"


def dump_value(value: Any) -> str:
    text = yaml.safe_dump(plain(value), default_flow_style=True, width=1 << 20)
    return text.removesuffix("\n").removesuffix("\n...").strip()


def plain(value: Any) -> Any:
    """Python's own types for what a sampler drew (NumPy's numbers and arrays)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


def as_config(items: Sequence[str]) -> dict[str, dict[str, Any]]:
    """`--set` items as a config file's sections ({"env": {...}, "agent": {...}}), the empty
    ones left out."""
    return {section: values for section, values in config.parse_set(items).items() if values}


def to_yaml(data: Mapping[str, Any]) -> str:
    return yaml.safe_dump(plain(dict(data)), sort_keys=False)
