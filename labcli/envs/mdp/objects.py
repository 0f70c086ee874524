"""What an arm's terms read besides the robot: a fixed base's frame, the free bodies it
handles (a cube to lift), as views of the sim's state, and the hand's offset to them. Terms
share them through `task.shared`: one per body, made in the first term's `__init__`."""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import torch

from labcli.envs.mdp import math, names, sensors
from labcli.errors import LabError

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask


class FixedFrame:
    """The pose (world frame) of a body bolted to the world, read once from the model's
    kinematics: it never moves. `local` and `world` turn positions `[n, 3]` into and out of
    it."""

    def __init__(self, task: RobotTask, body: str):
        if task.robot.floating:
            raise LabError(f"a term reads body '{body}' as a fixed base's frame, and model "
                           f"'{names.model_name(task.model)}' floats (a free joint)",
                           "use it on a robot bolted to the world (env.robot.base: fixed)")
        index = names.resolve_one(task.model, "body", body)
        data = mujoco.MjData(task.model)
        mujoco.mj_kinematics(task.model, data)
        self.pos = task.tiled(data.xpos[index].tolist())
        self.quat = task.tiled(data.xquat[index].tolist())
        self.quat_inverse = task.tiled((data.xquat[index] * [1, -1, -1, -1]).tolist())

    def local(self, pos_w: torch.Tensor) -> torch.Tensor:
        return math.quat_apply_inverse(self.quat, pos_w - self.pos)

    def world(self, pos: torch.Tensor) -> torch.Tensor:
        return math.quat_apply(self.quat, pos).add_(self.pos)


class FreeBody:
    """A body with a free joint: its position `pos` `[n, 3]` and orientation `quat` `[n, 4]`
    (world frame) as views of the sim's qpos; `qpos` and `qvel` its joint's slices."""

    def __init__(self, task: RobotTask, body: str):
        model = task.model
        index = names.resolve_one(model, "body", body)
        joint = int(model.body_jntadr[index])
        if joint < 0 or model.jnt_type[joint] != mujoco.mjtJoint.mjJNT_FREE:
            raise LabError(f"body '{body}' of model '{names.model_name(model)}' has no free "
                           "joint: a term of an object reads a free body",
                           "name a body with a free joint (an object the robot handles)")
        qa, da = int(model.jnt_qposadr[joint]), int(model.jnt_dofadr[joint])
        self.qpos, self.qvel = slice(qa, qa + 7), slice(da, da + 6)
        self.pos = task.sim.qpos[:, qa:qa + 3]
        self.height = task.sim.qpos[:, qa + 2]
        self.quat = task.sim.qpos[:, qa + 3:qa + 7]


class Grasp:
    """Whether each env's object is held, `[n]` (bool): every one of the finger bodies (their
    subtrees) touches it, and where `squeeze` is given, their contacts' net force is at most
    that share of the sum of their sizes. A pushed or batted object touches one finger at
    most; fingertips pressing it into the floor push it the same way, a grasp from opposing
    sides."""

    def __init__(self, task: RobotTask, body: str, fingers: list[str], squeeze: float | None):
        self.count, self.squeeze = len(fingers), squeeze
        self.contacts = sensors.columns(task, [[s.name] for s in grasp_sensors(body, fingers)])
        self.robot, self.key = task.robot, ("held", body, tuple(fingers), squeeze)

    def __call__(self) -> torch.Tensor:
        return self.robot.per_state(self.key, self._held)

    def _held(self) -> torch.Tensor:
        # Each sensor's 4 values: the number of contacts, then their net force (world frame).
        contacts = self.contacts().view(-1, self.count, 4)
        held = (contacts[:, :, 0] > 0).all(dim=1)
        if self.squeeze is not None:
            forces = contacts[:, :, 1:]
            net = torch.linalg.vector_norm(forces.sum(dim=1), dim=1)
            held &= net <= self.squeeze * torch.linalg.vector_norm(forces, dim=2).sum(dim=1)
        return held


class SiteToObject:
    """The vector from a site (an end effector) to an object's origin, world frame `[n, 3]`,
    once per state: the reach terms and observations of one hand and object share it."""

    def __init__(self, task: RobotTask, site: str, body: str):
        self.object = free_body(task, body)
        self.site = sensors.columns(task, [[s.name for s in site_sensors(site)]])
        self.robot, self.key = task.robot, ("site_to_object", site, body)

    def __call__(self) -> torch.Tensor:
        return self.robot.per_state(self.key, lambda: self.object.pos - self.site())


def site_sensors(site: str) -> list[sensors.Sensor]:
    """What `SiteToObject` reads of the site: its position."""
    return [sensors.frame("framepos", "site", site)]


def grasp_sensors(body: str, fingers: list[str]) -> list[sensors.Sensor]:
    return [sensors.subtree_contact(finger, body, "body") for finger in fingers]


def fixed_frame(task: RobotTask, body: str) -> FixedFrame:
    return task.shared(("fixed_frame", body), lambda: FixedFrame(task, body))


def free_body(task: RobotTask, body: str) -> FreeBody:
    return task.shared(("free_body", body), lambda: FreeBody(task, body))


def grasp(task: RobotTask, body: str, fingers: list[str], squeeze: float | None) -> Grasp:
    return task.shared(("grasp", body, tuple(fingers), squeeze),
                       lambda: Grasp(task, body, fingers, squeeze))


def site_to_object(task: RobotTask, site: str, body: str) -> SiteToObject:
    return task.shared(("site_to_object", site, body), lambda: SiteToObject(task, site, body))
