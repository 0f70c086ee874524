"""Offscreen images of one MuJoCo state, for videos; the GL backend is gl.py's choice."""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from labcli.envs.mdp import terrain_model
from labcli.envs.render import gl
from labcli.errors import LabError, first_line

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

    def render(self, qpos: torch.Tensor, qvel: torch.Tensor) -> np.ndarray:
        if self._renderer is None:
            unavailable()
            height, width = self.size
            try:
                self._renderer = mujoco.Renderer(self.model, height=height, width=width)
            except Exception as exc:  # no GL library, no display for glfw, a broken driver...
                raise render_error(exc) from exc
        self.sync(qpos, qvel)
        self._renderer.update_scene(self.data, camera=self.camera)
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()


def _following(model: mujoco.MjModel) -> mujoco.MjvCamera:
    """A camera that follows the robot from above and behind: on terrain a robot's own camera,
    level with it a metre or two to the side, looks into the walls of the next patch's stairs;
    a fixed view loses a robot that walks off. Tracks the floating base (the first body with a
    free joint), else the first body."""
    free = [b for b in range(1, model.nbody) if model.body_jntnum[b]
            and model.jnt_type[model.body_jntadr[b]] == mujoco.mjtJoint.mjJNT_FREE]
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    camera.trackbodyid = free[0] if free else min(1, model.nbody - 1)
    # Near enough to see a gait, far enough to see the robot whole and the steps around it: a
    # Go1 (its feet 0.48 m from its trunk) from 1.7 m, a G1 (0.77 m) from 2.7 m.
    camera.distance = max(3.5 * _reach(model, camera.trackbodyid), 1.0)
    camera.elevation, camera.azimuth = -30.0, 135.0
    return camera


def _reach(model: mujoco.MjModel, root: int) -> float:
    """How far the bodies under `root` reach from it in the model's own pose, in metres."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    under = [b for b in range(root, model.nbody) if _descends(model, b, root)]
    return float(np.linalg.norm(data.xpos[under] - data.xpos[root], axis=1).max())


def _descends(model: mujoco.MjModel, body: int, root: int) -> bool:
    while body > root:
        body = int(model.body_parentid[body])
    return body == root


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
