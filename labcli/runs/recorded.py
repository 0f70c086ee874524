"""The model a run recorded in its run.json (`labcli/envs/models.py`'s `describe`), and the task
spec that `lab play`, `lab export` and a resume build the run's env from: a Menagerie robot and
entry as recorded, whatever the task names now; a file, or a run from before runs recorded
their model, the task's current model."""

from __future__ import annotations

import dataclasses
from typing import Any

from labcli.envs import models
from labcli.envs.spec import Menagerie
from labcli.errors import LabError
from labcli.runs import rundir

MODEL = "model"  # run.json's field
MENAGERIE = "menagerie"


def record(run: rundir.Run) -> dict[str, Any] | None:
    """run.json's model, checked field by field (a run dir is data); None where it has none."""
    value = run.manifest().get(MODEL)
    if value is None:
        return None
    menagerie = value.get(MENAGERIE)
    if menagerie is None:
        return value
    if not (isinstance(menagerie, dict)
            and all(isinstance(menagerie.get(key), str) and menagerie[key]
                    for key in ("robot", "entry"))
            and all(isinstance(menagerie.get(key, ""), str)
                    for key in ("tree", "package", "commit", "root"))):
        raise LabError(f"{run.dir / rundir.MANIFEST} is damaged: its {MODEL!r} is {value!r}",
                       "restore or delete the file")
    return value


def recorded_model(run: rundir.Run) -> Menagerie | None:
    """The Menagerie robot and entry the run recorded; None for a file or no record."""
    found = record(run)
    if found is None or MENAGERIE not in found:
        return None
    return Menagerie(found[MENAGERIE]["robot"], found[MENAGERIE]["entry"])


def spec_of(run: rundir.Run, spec: Any) -> tuple[Any, str | None]:
    """`spec` with the model the run recorded, and a warning line where the installed
    registry's folder of that robot differs from the recorded one."""
    model = recorded_model(run)
    if model is None or not dataclasses.is_dataclass(spec) or not hasattr(spec, MODEL):
        return spec, None
    menagerie = record(run)[MENAGERIE]
    warning = models.changed_since(model, menagerie.get("tree"), menagerie.get("package"))
    return dataclasses.replace(spec, model=model), warning


def about(run: rundir.Run, spec: Any) -> dict[str, str]:
    """What `lab info --run` says of the run's model, as name → value (no download)."""
    built, warning = spec_of(run, spec)
    found = record(run)
    if not hasattr(built, MODEL):
        return {}
    rows = models.about(built.model)
    if found is None:
        rows["model"] += " (the task's current model: the run recorded none)"
    elif MENAGERIE in found:
        menagerie = found[MENAGERIE]
        rows["model recorded"] = models.version(
            menagerie.get("package"), menagerie.get("commit"), menagerie["robot"],
            menagerie.get("tree")) + (f", read from MENAGERIE_ROOT={menagerie['root']}"
                                      if "root" in menagerie else "")
    if warning is not None:
        rows["warning"] = warning
    return rows
