"""The wrapper pipeline: env wrappers (torch) → exactly one framework adapter → framework wrappers.

The order is checked before anything is built, so a wrong order is an error that names the
wrapper and the rule instead of a silent bug (Isaac Lab only says "must be applied last").
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from labcli import refs
from labcli.errors import LabError


class Stage(enum.IntEnum):
    ENV = 0  # torch in, torch out, on the LabVecEnv interface
    ADAPTER = 1  # converts to one library's env interface
    FRAMEWORK = 2  # takes that library's interface (e.g. SB3's VecNormalize)


@dataclass(frozen=True)
class WrapperSpec:
    """A wrapper a plugin registers. `build(env, **kwargs)` wraps an env: a callable, or a
    "module:attribute" string naming one, imported when first used. `framework` names the
    library an adapter converts to, or whose adapter a framework-stage wrapper needs; env-stage
    wrappers leave it None."""

    name: str
    stage: Stage
    build: Callable[..., Any] | str
    framework: str | None = None
    description: str = ""

    def wrap(self, env: Any, **kwargs: Any) -> Any:
        return refs.resolve(self.build, f"wrapper '{self.name}'")(env, **kwargs)


@dataclass(frozen=True)
class Step:
    """One wrapper in a pipeline, with its keyword arguments."""

    spec: WrapperSpec
    kwargs: dict[str, Any] = field(default_factory=dict)


def validate(pipeline: Sequence[Step], framework: str) -> None:
    """Raise a LabError naming the first wrapper out of place, and the rule it breaks."""
    adapters = [s.spec for s in pipeline if s.spec.stage is Stage.ADAPTER]
    if len(adapters) != 1:
        names = ", ".join(a.name for a in adapters) or "none"
        raise LabError(f"a pipeline needs exactly one framework adapter, got {names}",
                       f"use the '{framework}' adapter once, after every env wrapper")
    adapter = adapters[0]
    if adapter.framework != framework:
        raise LabError(f"adapter '{adapter.name}' converts for '{adapter.framework}', but the "
                       f"framework is '{framework}'", f"use the '{framework}' adapter")
    for before, after in zip(pipeline, pipeline[1:], strict=False):
        if after.spec.stage < before.spec.stage:
            raise LabError(
                f"wrapper '{after.spec.name}' ({after.spec.stage.name.lower()} stage) comes after "
                f"'{before.spec.name}' ({before.spec.stage.name.lower()} stage)",
                "order is env wrappers, then the one adapter, then framework wrappers")
    for step in pipeline:
        spec = step.spec
        if spec.stage is Stage.FRAMEWORK and spec.framework != adapter.framework:
            raise LabError(
                f"wrapper '{spec.name}' needs the '{spec.framework}' adapter, but the pipeline "
                f"uses '{adapter.name}' ({adapter.framework})",
                f"drop '{spec.name}' or train with --framework {spec.framework}")


def apply(env: Any, pipeline: Sequence[Step], framework: str) -> Any:
    """Validate `pipeline`, then wrap `env` in it, innermost first."""
    validate(pipeline, framework)
    for step in pipeline:
        env = step.spec.wrap(env, **step.kwargs)
    return env
