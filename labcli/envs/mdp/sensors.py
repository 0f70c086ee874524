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

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask

PREFIX = "lab:"
# A contact sensor's intprm: what it reports (the force), how contacts combine (their net
# force), and how many results (one).
_CONTACT_FORCE = 1 << int(mujoco.mjtConDataField.mjCONDATA_FORCE)
_NETFORCE = 3


@dataclass(frozen=True)
class Sensor:
    name: str
    kind: str  # "force", "torque", "contact", "jointactuatorfrc"
    target: str  # a body's name, or a joint's for jointactuatorfrc


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
    return Sensor(f"{PREFIX}jointactuatorfrc:{joint}", "jointactuatorfrc", joint)


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
        spec.add_sensor(name=sensor.name, type=mujoco.mjtSensor.mjSENS_CONTACT,
                        objtype=mujoco.mjtObj.mjOBJ_BODY, objname=sensor.target,
                        intprm=[_CONTACT_FORCE, _NETFORCE, 1])
    elif sensor.kind == "jointactuatorfrc":
        spec.add_sensor(name=sensor.name, type=mujoco.mjtSensor.mjSENS_JOINTACTFRC,
                        objtype=mujoco.mjtObj.mjOBJ_JOINT, objname=sensor.target)
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
    contacts above `threshold` (N). Terms on the same bodies and threshold share one
    computation per state."""

    def __init__(self, task: RobotTask, patterns: Sequence[str], threshold: float):
        self.bodies = body_names(task.model, patterns)
        self.forces = columns(task, [contact_names(b) for b in self.bodies])
        self.robot, self.threshold = task.robot, threshold
        self.key = ("in_contact", tuple(self.bodies), threshold)

    @staticmethod
    def sensors(model: mujoco.MjModel, patterns: Sequence[str]) -> list[Sensor]:
        return [contact(body) for body in body_names(model, patterns)]

    def __call__(self) -> torch.Tensor:
        return self.robot.per_state(self.key, lambda: torch.linalg.vector_norm(
            self.forces().view(-1, len(self.bodies), 3), dim=2) > self.threshold)
