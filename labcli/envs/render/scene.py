"""Offscreen images of one MuJoCo state, for videos; the GL backend is gl.py's choice."""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from labcli.envs import markers
from labcli.envs.mdp import terrain_model
from labcli.envs.mdp.robot_model import HOME
from labcli.envs.render import gl
from labcli.errors import LabError, first_line
from labcli.mjtree import in_subtree, robot_free_joints

WIDTH, HEIGHT = 320, 240


class SceneRenderer:
    """Renders the state of one env of a batch through the model's first camera, or a camera
    that follows the robot where the model has none (Menagerie's Go2) or stands on terrain. The
    GL context is made on the first `render`, so `sync` alone (for the viewer) needs none."""

    def __init__(self, model: mujoco.MjModel, width: int = WIDTH, height: int = HEIGHT):
        self.model = model
        self.data = mujoco.MjData(model)
        # The offscreen buffer bounds the image; a larger request would be refused.
        self.size = (min(height, model.vis.global_.offheight),
                     min(width, model.vis.global_.offwidth))
        self.camera: int | mujoco.MjvCamera = 0
        if not model.ncam or terrain_model.geom_ids(model):
            self.camera = _following(model)
        self._renderer: mujoco.Renderer | None = None

    def sync(self, qpos: torch.Tensor, qvel: torch.Tensor) -> mujoco.MjData:
        """Put one env's state into `data` with its derived quantities (positions of bodies)."""
        self.data.qpos[:] = qpos.detach().cpu().numpy()
        self.data.qvel[:] = qvel.detach().cpu().numpy()
        mujoco.mj_forward(self.model, self.data)
        return self.data

    def render(self, qpos: torch.Tensor, qvel: torch.Tensor,
               shown: list[markers.Marker] | None = None) -> np.ndarray:
        if self._renderer is None:
            unavailable()
            height, width = self.size
            try:
                self._renderer = mujoco.Renderer(self.model, height=height, width=width)
            except Exception as exc:  # no GL library, no display for glfw, a broken driver...
                raise render_error(exc) from exc
        self.sync(qpos, qvel)
        self._renderer.update_scene(self.data, camera=self.camera)
        markers.draw(self._renderer.scene, shown or [])
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()


def _following(model: mujoco.MjModel) -> mujoco.MjvCamera:
    """A camera that follows the robot from above and behind: on terrain a robot's own camera,
    level with it a metre or two to the side, looks into the walls of the next patch's stairs;
    a fixed view loses a robot that walks off. Tracks the floating base (or a planar one's
    root body, which slides); a robot bolted to the world (an arm) is framed where it works
    instead: its bodies in its default pose, from the front and above."""
    free = robot_free_joints(model)
    root = int(model.body_rootid[model.jnt_bodyid[model.actuator_trnid[0, 0]]]) \
        if model.nu else min(1, model.nbody - 1)
    camera = mujoco.MjvCamera()
    camera.elevation, camera.azimuth = -30.0, 135.0
    joints = range(model.body_jntadr[root], model.body_jntadr[root] + model.body_jntnum[root])
    planar = any(model.jnt_type[j] == mujoco.mjtJoint.mjJNT_SLIDE for j in joints)
    if free or planar:
        camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        camera.trackbodyid = int(model.jnt_bodyid[free[0]]) if free else root
        # Near enough to see a gait, far enough to see the robot whole and the steps around
        # it: a Go1 (its feet 0.48 m from its trunk) from 1.7 m, a G1 (0.77 m) from 2.7 m.
        positions = _positions(model, camera.trackbodyid)
        reach = np.linalg.norm(positions - positions[0], axis=1).max()
        camera.distance = max(3.5 * float(reach), 1.0)
        return camera
    positions = _positions(model, root, key=HOME)
    low, high = positions.min(axis=0), positions.max(axis=0)
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = (low + high) / 2.0
    # A Panda in its default pose (about 0.7 m across) from 1.5 m.
    camera.distance = max(2.0 * float(np.linalg.norm(high - low)), 0.5)
    camera.elevation, camera.azimuth = -25.0, 150.0
    return camera


def _positions(model: mujoco.MjModel, root: int, key: str | None = None) -> np.ndarray:
    """The positions (world frame) of `root` and the bodies under it, `root` first: in the
    keyframe `key` where the model has it, else in the model's own pose."""
    data = mujoco.MjData(model)
    if key is not None and mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, key) >= 0:
        mujoco.mj_resetDataKeyframe(model, data, model.key(key).id)
    mujoco.mj_kinematics(model, data)
    under = [b for b in range(root, model.nbody) if in_subtree(model, b, root)]
    return data.xpos[under]


def unavailable() -> None:
    """Raise the one line that says why nothing can render here, if nothing can."""
    if gl.choice.backend is None:
        raise LabError(f"offscreen rendering is unavailable: {gl.choice.problem}",
                       "--video needs it; training and playing without --video do not")


def render_error(exc: BaseException) -> LabError:
    return LabError(
        f"offscreen rendering failed with MUJOCO_GL={gl.backend()}: {first_line(exc)}",
        f"on Debian/Ubuntu install {gl.PACKAGES['egl']} and use MUJOCO_GL=egl "
        "(lab's default without a display)")
