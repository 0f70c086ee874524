"""A snapshot of what a resumed run needs besides the framework's checkpoint to go on exactly as
a run that never stopped: the env's episodes in flight and the process's random generators.
Saved as `state_<iteration>.pt` beside the checkpoint of that iteration."""

from __future__ import annotations

import random
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from labcli.errors import LabError, first_line
from labcli.plugins.policy import read_torch_file

PREFIX = "state_"


def seed_all(seed: int) -> None:
    """Seed every generator a learning library may draw from: Python's, NumPy's (SB3 shuffles
    its minibatches with it) and torch's (action sampling, network initialization)."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def rng_state() -> dict[str, Any]:
    """The process-wide generators' states, as tensors and plain numbers (no pickled objects:
    state files load with `weights_only=True`)."""
    kind, keys, pos, has_gauss, gauss = np.random.get_state()
    version, internal, gauss_next = random.getstate()
    return {
        "torch": torch.get_rng_state(),
        "numpy": {"kind": kind, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": pos,
                  "has_gauss": has_gauss, "gauss": gauss},
        "python": {"version": version, "internal": list(internal), "gauss_next": gauss_next},
    }


def set_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    n = state["numpy"]
    np.random.set_state((n["kind"], n["keys"].numpy().astype(np.uint32), n["pos"],
                         n["has_gauss"], n["gauss"]))
    p = state["python"]
    random.setstate((p["version"], tuple(p["internal"]), p["gauss_next"]))


def path_of(run_dir: Path, iteration: int) -> Path:
    return run_dir / f"{PREFIX}{iteration}.pt"


def writer(iteration: int, state: dict[str, Any]) -> Callable[[Path], None]:
    """What writes `state` as `state_<iteration>.pt` into a checkpoint's staging directory
    (labcli/runs/checkpoints.py publishes it with the framework's files)."""
    return lambda directory: torch.save(state, path_of(directory, iteration))


def load(path: Path) -> dict[str, Any] | None:
    """The saved state, checked to be what `rng_state` and the env wrote; None when the
    checkpoint has none (written before lab saved it)."""
    if not path.exists():
        return None
    state = read_torch_file(path, what="resume state")
    try:
        _check(state)
    except (TypeError, ValueError, KeyError, RuntimeError, IndexError, AttributeError) as exc:
        raise LabError(f"resume state {path} is damaged: {first_line(exc)}",
                       "delete it to resume without it (new episodes, new random numbers)"
                       ) from None
    return state


def _check(state: Any) -> None:
    """Raises what a damaged state would raise later, now: the generators' states are tried on
    fresh generators of each kind."""
    if not isinstance(state, dict):
        raise TypeError(f"it holds a {type(state).__name__}")
    for key in ("iteration", "steps"):
        if not isinstance(state.get(key), int) or state[key] < 0:
            raise ValueError(f"its {key} is {state.get(key)!r}")
    if state.get("env") is not None and not isinstance(state["env"], dict):
        raise TypeError(f"its env state is a {type(state['env']).__name__}")
    _check_rng(state.get("rng"))
    others = state.get("ranks", [])  # a data-parallel run's ranks other than 0
    if not isinstance(others, list):
        raise TypeError(f"its ranks are a {type(others).__name__}")
    for part in others:
        if not isinstance(part, dict) or not isinstance(part.get("env"), dict | None):
            raise TypeError("a rank's state is not a mapping of env and generators")
        _check_rng(part.get("rng"))


def _check_rng(rng: Any) -> None:
    if not isinstance(rng, dict):
        raise TypeError("it has no random generator states")
    torch.Generator().set_state(rng["torch"])
    n, p = rng["numpy"], rng["python"]
    np.random.RandomState().set_state((n["kind"], n["keys"].numpy().astype(np.uint32), n["pos"],
                                       n["has_gauss"], n["gauss"]))
    random.Random().setstate((p["version"], tuple(p["internal"]), p["gauss_next"]))
