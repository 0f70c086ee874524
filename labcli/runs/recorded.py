"""The model a run recorded in its run.json (`labcli/envs/models.py`'s `describe`), and the task
spec that `lab play`, `lab export` and a resume build the run's env from: a Menagerie robot and
entry, or a file that an installed task names as its model, as recorded, whatever the task names
now; a run from before runs recorded their model, or whose file no installed task names, the
task's current model (a run dir is data: lab opens no other file it names), silently where that
file is of the content the run recorded."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from labcli import files
from labcli.envs import models
from labcli.envs.spec import Menagerie
from labcli.errors import LabError
from labcli.plugins import registry
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


def recorded_model(found: dict[str, Any] | None) -> Menagerie | Path | None:
    """The Menagerie robot and entry, or the file, of a run's record (`record`'s); None for
    no record."""
    if found is None:
        return None
    if MENAGERIE in found:
        return Menagerie(found[MENAGERIE]["robot"], found[MENAGERIE]["entry"])
    file = found.get("file")
    return Path(file) if isinstance(file, str) and file else None


def _installed_model_files() -> set[Path]:
    """The model files that installed tasks name: the only files a run's record may point to."""
    tasks = registry.loaded()
    files = (getattr(tasks.get(registry.TASK, name), MODEL, None)
             for name in tasks.names(registry.TASK))
    return {file for file in files if isinstance(file, Path)}


def _same_content(digest: Any, model: Any) -> bool:
    """Whether `model` is a file whose sha256 is the recorded `digest`."""
    return (isinstance(digest, str) and isinstance(model, Path) and files.is_regular(model)
            and files.sha256(model) == digest)


def spec_of(run: rundir.Run, spec: Any) -> tuple[Any, str | None]:
    """`spec` with the model the run recorded, and a warning line where that model is not the
    one the run trained on: the installed registry's folder of its robot differs from the
    recorded one, or its file is no installed task's model (the task's current model
    instead) and the task's file is not of the content the run recorded (a run trained on
    another host names the file where that host installed it)."""
    found = record(run)
    model = recorded_model(found)
    if model is None or not dataclasses.is_dataclass(spec) or not hasattr(spec, MODEL):
        return spec, None
    if isinstance(model, Path):
        if model == spec.model or model in _installed_model_files():
            return dataclasses.replace(spec, model=model), None
        if _same_content(found.get("sha256"), spec.model):
            return spec, None  # the task's file, where the run's host installed it elsewhere
        return spec, (f"the run's model {model} is no installed task's model (lab opens no "
                      "other file a run names): its env is built on the task's current model, "
                      f"{models.about_line(spec.model)}")
    menagerie = found[MENAGERIE]
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
