"""Which OpenGL backend MuJoCo renders with. MuJoCo reads MUJOCO_GL once, when it is first
imported, so `labcli/__init__.py` settles it before anything imports mujoco."""

from __future__ import annotations

import os
import sys

MUJOCO_GL = "MUJOCO_GL"
# Headless default: EGL renders offscreen without a display, on a GPU's driver or, with Debian's
# libegl1 and libgl1-mesa-dri, in software. OSMesa was seen to fail in its cleanup.
HEADLESS = "egl"
DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY")

# Whether lab chose MUJOCO_GL (True) or found it set by the user (False); `lab info` shows it.
chosen_by_lab = False


def has_display() -> bool:
    """A window can open: always assumed off Linux, where a display server is named otherwise."""
    if not sys.platform.startswith("linux"):
        return True
    return any(os.environ.get(name) for name in DISPLAY_VARIABLES)


def set_default() -> None:
    """Use EGL where MUJOCO_GL is unset and no display exists; elsewhere leave MuJoCo's own
    choice (GLFW), which the interactive viewer needs."""
    global chosen_by_lab
    if MUJOCO_GL not in os.environ and not has_display():
        os.environ[MUJOCO_GL] = HEADLESS
        chosen_by_lab = True


def backend() -> str:
    """The backend MuJoCo uses in this process: MUJOCO_GL, or its default, glfw."""
    return os.environ.get(MUJOCO_GL) or "glfw"
