"""`lab play --viewer`: env 0 in MuJoCo's interactive viewer, where a display exists."""

from __future__ import annotations

import threading
import time
from typing import Any

import gymnasium as gym

from labcli.envs import markers
from labcli.envs.render import gl
from labcli.errors import LabError

CLOSE_TIMEOUT_S = 10.0


def check_display() -> None:
    if not gl.has_display():
        raise LabError("--viewer needs a display, and none is set (no DISPLAY or "
                       "WAYLAND_DISPLAY)", "record a video with --video instead, or run where "
                       "a display exists: a desktop session or ssh -X")


class Viewer(gym.vector.VectorWrapper):
    """Shows env 0 after every step at real time; `running` turns False once the window is
    closed, which ends the rollout."""

    def __init__(self, env: gym.vector.VectorEnv):
        check_display()
        super().__init__(env)
        import mujoco
        import mujoco.viewer

        model, data = env.unwrapped.mj_scene()
        before = set(threading.enumerate())
        self._handle = mujoco.viewer.launch_passive(model, data)
        # The viewer's GUI thread: `close` must wait for it, or GLFW's exit handler tears GLFW
        # down under it (seen as a segfault at exit on Xvfb).
        self._threads = set(threading.enumerate()) - before
        if model.ncam:  # the view the videos show; the mouse still moves a free camera
            with self._handle.lock():
                self._handle.cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
                self._handle.cam.fixedcamid = 0
        self._dt = env.unwrapped.step_dt
        self._next = time.perf_counter()

    def __getattr__(self, name: str) -> Any:
        if name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)

    @property
    def running(self) -> bool:
        return self._handle.is_running()

    def step(self, actions: Any):
        result = self.env.step(actions)
        with self._handle.lock():
            self.env.unwrapped.mj_scene()  # copies env 0's state into the viewer's MjData
            self._handle.user_scn.ngeom = 0
            markers.draw(self._handle.user_scn, self.env.unwrapped.markers())
        self._handle.sync()
        self._next += self._dt
        time.sleep(max(0.0, self._next - time.perf_counter()))
        return result

    def close(self, **kwargs: Any) -> None:
        self._handle.close()
        for thread in self._threads:
            thread.join(timeout=CLOSE_TIMEOUT_S)
        self.env.close(**kwargs)
