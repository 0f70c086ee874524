"""Where a task's MuJoCo model comes from: an MJCF file, or a robot of MuJoCo Menagerie loaded
by name through the `mujoco-menagerie` package, which downloads the robot's folder once into its
cache (`MENAGERIE_CACHE_DIR`, default `~/.cache/mujoco-menagerie`) or reads an offline copy of
Menagerie's folders (`MENAGERIE_ROOT`). Either way the task gets an `MjSpec` to edit before it
compiles it, and a description of the model that a run records."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Any

import mujoco

from labcli.envs.spec import Menagerie
from labcli.errors import LabError

ModelSource = Path | Menagerie

OFFLINE_HINT = ("connect to the internet once, so that the model downloads into its cache "
                "(MENAGERIE_CACHE_DIR), or point MENAGERIE_ROOT at a copy of Menagerie's "
                "robot folders")


def load_spec(source: ModelSource) -> mujoco.MjSpec:
    """The model as an editable `MjSpec`; a LabError (one line, the ways out) where a
    Menagerie robot can be neither found nor downloaded."""
    if isinstance(source, Menagerie):
        return mujoco.MjSpec.from_file(str(menagerie_xml(source)))
    try:
        return mujoco.MjSpec.from_file(str(source))
    except (ValueError, FileNotFoundError) as exc:
        raise LabError(f"the model {source} does not load: {str(exc).splitlines()[0]}",
                       "reinstall the task's package") from None


def menagerie_xml(source: Menagerie) -> Path:
    """The entry point's MJCF on disk, the robot's folder downloaded first if need be."""
    import mujoco_menagerie as mm

    try:
        robot = mm.get(source.robot)
        entry = robot.entry(source.entry)
        folder = robot.path(progress=_progress)
    except mm.UnknownRobotError:
        raise LabError(f"MuJoCo Menagerie has no robot '{source.robot}'",
                       f"name one of {', '.join(mm.names())}") from None
    except mm.UnknownEntryPointError:
        raise LabError(f"Menagerie's {source.robot} has no entry '{source.entry}'",
                       f"name one of {', '.join(mm.get(source.robot).entry_names)}") from None
    except mm.MenagerieError as exc:
        raise LabError(f"Menagerie's {source.robot} could not be loaded: "
                       f"{str(exc).splitlines()[0]}", OFFLINE_HINT) from None
    path = folder / entry.file
    if not path.is_file():
        raise LabError(f"Menagerie's {source.robot} has no {entry.file} in {folder}",
                       "point MENAGERIE_ROOT at a complete copy of the robot's folder")
    return path


def describe(source: ModelSource) -> dict[str, Any]:
    """What a run records of its model, so that `lab play` of it later finds the same one: a
    file's path; a Menagerie robot's name, entry, the package's version, the Menagerie commit
    its registry names and the robot folder's tree id (or the offline copy it read)."""
    if not isinstance(source, Menagerie):
        return {"file": str(source)}
    import mujoco_menagerie as mm

    described: dict[str, Any] = {"menagerie": {"robot": source.robot, "entry": source.entry,
                                               "package": mm.__version__,
                                               "commit": mm.commit()}}
    with contextlib.suppress(mm.MenagerieError):
        described["menagerie"]["tree"] = mm.get(source.robot).oid
    root = os.environ.get("MENAGERIE_ROOT")
    if root:
        described["menagerie"]["root"] = root
    return described


def _progress(name: str, done: int, total: int) -> None:
    """The download's progress on stderr, one line redrawn (rich, as a run's progress)."""
    from rich.console import Console

    console = Console(stderr=True)
    size = f"{done / 2**20:.1f}/{total / 2**20:.1f} MiB" if total else f"{done / 2**20:.1f} MiB"
    console.print(f"downloading MuJoCo Menagerie's {name}: {size}", end="\r",
                  highlight=False)
    if total and done >= total:
        console.print()
