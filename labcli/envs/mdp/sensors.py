"""The MuJoCo sensors robot terms read: a term lists the sensors it needs, the task adds them to
the model before compiling it (`RobotTask.build_model`), and the term reads their columns of
`sim.sensordata`, on both backends alike."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import mujoco
import torch

from labcli.envs.mdp import names
from labcli.envs.mdp.robot import columns as state_columns
from labcli.errors import LabError
from labcli.mjtree import in_subtree

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask

PREFIX = "lab:"
# A contact sensor's intprm: what it reports (a bit per field: the number of contacts matched,
# their force), how contacts combine (MuJoCo's reductions by number) and how many results.
_CONTACT_FIELDS = {"found": mujoco.mjtConDataField.mjCONDATA_FOUND,
                   "force": mujoco.mjtConDataField.mjCONDATA_FORCE}
_REDUCE = {"none": 0, "mindist": 1, "maxforce": 2, "netforce": 3}
# How a sensor's target (and a contact sensor's `ref`) is matched: a body's inertial frame, its
# own frame (`xbody`; for a contact sensor, any body of its subtree), a site, a joint.
_OBJTYPES = {"body": mujoco.mjtObj.mjOBJ_BODY, "xbody": mujoco.mjtObj.mjOBJ_XBODY,
             "site": mujoco.mjtObj.mjOBJ_SITE, "joint": mujoco.mjtObj.mjOBJ_JOINT}
# Sensors whose value is one MuJoCo sensor on the target as it is (frame sensors: world frame).
_PLAIN = {"framepos": mujoco.mjtSensor.mjSENS_FRAMEPOS,
          "framequat": mujoco.mjtSensor.mjSENS_FRAMEQUAT,
          "framexaxis": mujoco.mjtSensor.mjSENS_FRAMEXAXIS,
          "frameyaxis": mujoco.mjtSensor.mjSENS_FRAMEYAXIS,
          "framelinvel": mujoco.mjtSensor.mjSENS_FRAMELINVEL,
          "frameangvel": mujoco.mjtSensor.mjSENS_FRAMEANGVEL,
          "subtreeangmom": mujoco.mjtSensor.mjSENS_SUBTREEANGMOM,
          "jointactuatorfrc": mujoco.mjtSensor.mjSENS_JOINTACTFRC}


@dataclass(frozen=True)
class Sensor:
    name: str
    kind: str  # "force", "torque", "contact", or one of _PLAIN's
    target: str  # a body's, site's or joint's name
    objtype: str = "body"  # how `target` is matched: a key of _OBJTYPES
    # Contact sensors only: the other side (None: anything), how it is matched, the fields
    # reported per result, how contacts combine and how many results.
    ref: str | None = None
    reftype: str = "body"
    fields: tuple[str, ...] = ("force",)
    reduce: str = "netforce"
    num: int = 1


def check(model: mujoco.MjModel, sensor: Sensor, reader: str) -> None:
    """A one-line error if the sensor's target or contact reference is not in `model` (the
    closest names the model has: MuJoCo's own compile error is a traceback), or if it reads
    the contacts of a body none of whose geoms touches anything: `reader` (the term's key)
    would read zeros forever."""
    for target, objtype in ((sensor.target, sensor.objtype), (sensor.ref, sensor.reftype)):
        if target is not None:
            names.resolve_one(model, "body" if objtype == "xbody" else objtype, target)
    if (sensor.kind == "contact" and sensor.objtype in ("body", "xbody")
            and not _touches(model, model.body(sensor.target).id, sensor.objtype == "xbody")):
        raise LabError(f"{reader} reads the contacts of body '{sensor.target}', but none of "
                       "its geoms touches anything (contype and conaffinity 0, in no contact "
                       "pair)", "give it an entry in env.robot.collisions, which leaves the "
                       "bodies it does not name without collisions, or set the term to null")


def _touches(model: mujoco.MjModel, body: int, subtree: bool) -> bool:
    """Whether a geom of `body` (with `subtree`, of any body under it) may touch something."""
    paired = {int(g) for g in (*model.pair_geom1, *model.pair_geom2)}
    for g in range(model.ngeom):
        owner = int(model.geom_bodyid[g])
        if (in_subtree(model, owner, body) if subtree else owner == body) and (
                model.geom_contype[g] or model.geom_conaffinity[g] or g in paired):
            return True
    return False


def body_names(model: mujoco.MjModel, patterns: Sequence[str]) -> list[str]:
    all_bodies = names.all_names(model, "body")
    return [all_bodies[i] for i in names.resolve(model, "body", patterns)]


def wrench_names(body: str) -> list[str]:
    return [f"{PREFIX}force:{body}", f"{PREFIX}torque:{body}"]


def wrench(body: str) -> list[Sensor]:
    force, torque = wrench_names(body)
    return [Sensor(force, "force", body), Sensor(torque, "torque", body)]


def contact_names(body: str) -> list[str]:
    return [f"{PREFIX}contact:{body}"]


def contact(body: str) -> Sensor:
    return Sensor(contact_names(body)[0], "contact", body)


def joint_torque(joint: str) -> Sensor:
    return Sensor(f"{PREFIX}jointactuatorfrc:{joint}", "jointactuatorfrc", joint, "joint")


def frame(kind: str, objtype: str, target: str) -> Sensor:
    """A frame sensor (`framepos`, `framequat`, `framexaxis`, `frameyaxis`, `framelinvel`,
    `frameangvel`: in the world frame) on a site or a body's own frame (`xbody`)."""
    return Sensor(f"{PREFIX}{kind}:{objtype}:{target}", kind, target, objtype)


def subtree_angmom(body: str) -> Sensor:
    """The angular momentum of `body`'s subtree about its center of mass (world frame)."""
    return Sensor(f"{PREFIX}subtreeangmom:{body}", "subtreeangmom", body)


def subtree_contact(body: str, ref: str, reftype: str) -> Sensor:
    """The contacts between `body`'s subtree and `ref`: how many (found) and their net force
    (N, world frame), 4 values."""
    return Sensor(f"{PREFIX}contact:subtree:{body}:{reftype}:{ref}", "contact", body, "xbody",
                  ref=ref, reftype=reftype, fields=("found", "force"))


def self_contacts(body: str, num: int) -> Sensor:
    """The `num` contacts of largest force between bodies of `body`'s subtree: each one's force
    (N, in its contact's frame; zeros past the contacts there are), `3 num` values."""
    return Sensor(f"{PREFIX}self_contacts:{body}:{num}", "contact", body, "xbody", ref=body,
                  reftype="xbody", reduce="maxforce", num=num)


def add(spec: mujoco.MjSpec, sensor: Sensor) -> None:
    """Add `sensor` to `spec` (once: terms may share one)."""
    if any(s.name == sensor.name for s in spec.sensors):
        return
    if sensor.kind in ("force", "torque"):
        site = f"{PREFIX}{sensor.target}"
        if not any(s.name == site for s in spec.sites):
            spec.body(sensor.target).add_site(name=site, pos=[0, 0, 0])
        kind = (mujoco.mjtSensor.mjSENS_FORCE if sensor.kind == "force"
                else mujoco.mjtSensor.mjSENS_TORQUE)
        spec.add_sensor(name=sensor.name, type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE,
                        objname=site)
    elif sensor.kind == "contact":
        fields = sum(1 << int(_CONTACT_FIELDS[f]) for f in sensor.fields)
        ref = ({} if sensor.ref is None else
               {"reftype": _OBJTYPES[sensor.reftype], "refname": sensor.ref})
        spec.add_sensor(name=sensor.name, type=mujoco.mjtSensor.mjSENS_CONTACT,
                        objtype=_OBJTYPES[sensor.objtype], objname=sensor.target,
                        intprm=[fields, _REDUCE[sensor.reduce], sensor.num], **ref)
    elif sensor.kind in _PLAIN:
        spec.add_sensor(name=sensor.name, type=_PLAIN[sensor.kind],
                        objtype=_OBJTYPES[sensor.objtype], objname=sensor.target)
    else:
        raise ValueError(f"unknown sensor kind {sensor.kind!r}")


def columns(task: RobotTask, groups: Sequence[Sequence[str]]) -> Callable[[], torch.Tensor]:
    """A function returning the named sensors' values, `[num_envs, total dim]`, in order: a
    view where their columns are consecutive, else gathered into a buffer made once."""
    model = task.model
    addresses = []
    for group in groups:
        for name in group:
            sid = names.resolve_one(model, "sensor", name)
            start = int(model.sensor_adr[sid])
            addresses.extend(range(start, start + int(model.sensor_dim[sid])))
    data = task.sim.sensordata
    view, index = state_columns(data, addresses)
    if index is None:
        return lambda: view
    return lambda: torch.index_select(data, 1, index, out=view)


class BodyContacts:
    """Whether each of the named bodies is in contact, `[n, bodies]`: the net force of its
    contacts above `threshold` (N); with `against` (a body), of its subtree's contacts with
    that body's geoms. Terms on the same bodies, threshold and other side share one
    computation per state."""

    def __init__(self, task: RobotTask, patterns: Sequence[str], threshold: float,
                 against: str | None = None):
        self.bodies = body_names(task.model, patterns)
        self.forces = columns(task, [[s.name] for s in self.sensors(task.model, patterns,
                                                                    against)])
        # A sensor against a body reports the number of contacts before their net force.
        self.width = 3 if against is None else 4
        self.robot, self.threshold = task.robot, threshold
        self.key = ("in_contact", tuple(self.bodies), threshold, against)

    @staticmethod
    def sensors(model: mujoco.MjModel, patterns: Sequence[str],
                against: str | None = None) -> list[Sensor]:
        bodies = body_names(model, patterns)
        if against is None:
            return [contact(body) for body in bodies]
        return [subtree_contact(body, against, "body") for body in bodies]

    def __call__(self) -> torch.Tensor:
        return self.robot.per_state(self.key, lambda: torch.linalg.vector_norm(
            self.forces().view(-1, len(self.bodies), self.width)[:, :, -3:], dim=2)
            > self.threshold)
