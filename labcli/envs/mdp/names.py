"""Names in a MuJoCo model resolved to ids once, with a one-line error naming the model and the
closest names when one is missing."""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterable

import mujoco

from labcli.errors import LabError

KINDS = {
    "body": mujoco.mjtObj.mjOBJ_BODY, "joint": mujoco.mjtObj.mjOBJ_JOINT,
    "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR, "site": mujoco.mjtObj.mjOBJ_SITE,
    "sensor": mujoco.mjtObj.mjOBJ_SENSOR, "geom": mujoco.mjtObj.mjOBJ_GEOM,
    "key": mujoco.mjtObj.mjOBJ_KEY,
}
COUNTS = {"body": "nbody", "joint": "njnt", "actuator": "nu", "site": "nsite",
          "sensor": "nsensor", "geom": "ngeom", "key": "nkey"}


def all_names(model: mujoco.MjModel, kind: str) -> list[str]:
    objtype = KINDS[kind]
    return [mujoco.mj_id2name(model, objtype, i) or "" for i in range(getattr(model, COUNTS[kind]))]


def model_name(model: mujoco.MjModel) -> str:
    # The <mujoco model="..."> attribute: MjModel keeps it first in its names buffer.
    return model.names[:model.names.index(b"\0")].decode() or "the model"


def resolve(model: mujoco.MjModel, kind: str, patterns: Iterable[str]) -> list[int]:
    """Ids of the `kind` objects whose names match `patterns` (full-match regular expressions,
    so a plain name matches itself), in model order; each pattern must match at least one."""
    names = all_names(model, kind)
    ids: set[int] = set()
    for pattern in patterns:
        try:
            regex = re.compile(pattern)
        except re.error as exc:
            raise LabError(f"'{pattern}' is not a valid name pattern ({exc})",
                           f"give {kind} names, or regular expressions such as '.*_foot'"
                           ) from None
        found = [i for i, name in enumerate(names) if regex.fullmatch(name)]
        if not found:
            close = difflib.get_close_matches(pattern, [n for n in names if n], n=3)
            plural = "bodies" if kind == "body" else f"{kind}s"
            hint = (f"did you mean {', '.join(repr(c) for c in close)}?" if close else
                    f"its {plural} are {', '.join(repr(n) for n in names if n) or 'unnamed'}")
            raise LabError(f"model '{model_name(model)}' has no {kind} named '{pattern}'", hint)
        ids.update(found)
    return sorted(ids)


def resolve_one(model: mujoco.MjModel, kind: str, name: str) -> int:
    return resolve(model, kind, [re.escape(name)])[0]
