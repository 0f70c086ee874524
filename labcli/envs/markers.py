"""Markers: what a task shows in videos and the viewer beside its bodies (a commanded target),
drawn into MuJoCo's scene after the model's own geoms, without touching the physics."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

AXIS_COLORS = ((0.9, 0.2, 0.2, 1.0), (0.2, 0.8, 0.2, 1.0), (0.2, 0.4, 0.9, 1.0))


@dataclass(frozen=True)
class Marker:
    """A target's position (m) and orientation (unit quaternion w, x, y, z), world frame."""

    pos: list[float]
    quat: list[float]
    radius: float = 0.02
    axis_length: float = 0.08


def draw(scene: mujoco.MjvScene, markers: list[Marker]) -> None:
    """Each marker as a translucent sphere with its frame's axes (x red, y green, z blue),
    added to `scene` while it has room."""
    for marker in markers:
        pos = np.asarray(marker.pos, dtype=np.float64)
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, np.asarray(marker.quat, dtype=np.float64))
        _add(scene, mujoco.mjtGeom.mjGEOM_SPHERE, [marker.radius] * 3, pos, rotation,
             (1.0, 0.6, 0.1, 0.5))
        for axis, color in enumerate(AXIS_COLORS):
            end = pos + marker.axis_length * rotation.reshape(3, 3)[:, axis]
            geom = _add(scene, mujoco.mjtGeom.mjGEOM_CAPSULE, [0.0] * 3, pos, np.eye(3).ravel(),
                        color)
            if geom is not None:
                mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, 0.004, pos, end)


def _add(scene: mujoco.MjvScene, kind: int, size, pos, rotation, rgba) -> mujoco.MjvGeom | None:
    if scene.ngeom >= scene.maxgeom:
        return None
    geom = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(geom, kind, np.asarray(size, dtype=np.float64), pos, rotation,
                        np.asarray(rgba, dtype=np.float32))
    scene.ngeom += 1
    return geom
