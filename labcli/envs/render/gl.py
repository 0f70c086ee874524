"""Which OpenGL backend MuJoCo renders with. MuJoCo reads MUJOCO_GL once, when it is first
imported, and a value whose library cannot load makes that import fail (on some versions with an
AttributeError from deep inside PyOpenGL), taking every command with it, `lab --version`
included. So `labcli/__init__.py` settles it first: a backend is only handed to MuJoCo if its
libraries load, and otherwise rendering is turned off for this process and the reason kept, for
the one line that `--video`, `lab info` and the viewer then say."""

from __future__ import annotations

import ctypes
import os
import sys
from dataclasses import dataclass

MUJOCO_GL = "MUJOCO_GL"
OFF = "disable"  # MuJoCo imports without any GL backend, renders nothing
OFF_VALUES = ("disable", "disabled", "off", "false", "0")
# Without a display, tried in this order: EGL renders offscreen on a GPU's driver or, with
# Debian's libegl1 and libgl1-mesa-dri, in software; OSMesa in software.
HEADLESS = ("egl", "osmesa")
# The libraries PyOpenGL loads for each backend: one of each group must load.
LIBRARIES = {"egl": (("EGL",), ("GL", "OpenGL", "GLESv2")), "osmesa": (("OSMesa",),)}
PACKAGES = {"egl": "libegl1 and libgl1-mesa-dri", "osmesa": "libosmesa6"}
DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY")


def valid_backends() -> tuple[str, ...]:
    """The MUJOCO_GL values MuJoCo accepts on this platform (as its own check has them)."""
    if sys.platform.startswith("linux"):
        return ("glfw", "egl", "osmesa", "glx")
    return ("glfw", "wgl") if sys.platform == "win32" else ("glfw", "cgl")


@dataclass(frozen=True)
class Choice:
    """The backend MuJoCo renders with (None: none can), who chose it, and why none can."""

    backend: str | None
    origin: str
    problem: str | None = None


choice = Choice("glfw", "MuJoCo's default")


def has_display() -> bool:
    """A window can open: always assumed off Linux, where a display server is named otherwise."""
    if not sys.platform.startswith("linux"):
        return True
    return any(os.environ.get(name) for name in DISPLAY_VARIABLES)


def loads(backend: str) -> str | None:
    """None when `backend`'s libraries load in this process, else what is missing. Loading is
    the only honest test: a library can be present and broken, or absent from ldconfig's cache
    and found through LD_LIBRARY_PATH."""
    for group in LIBRARIES.get(backend, ()):
        if not any(_loads(name) for name in group):
            return f"no lib{group[0]}.so loads"
    return None


def _loads(name: str) -> bool:
    # The names PyOpenGL tries: libX.so, then libX.so.9 down to libX.so.0.
    for filename in (f"lib{name}.so", *(f"lib{name}.so.{i}" for i in range(9, -1, -1))):
        try:
            ctypes.CDLL(filename, mode=ctypes.RTLD_GLOBAL)
        except OSError:
            continue
        return True
    return False


def settle() -> Choice:
    """Decide MUJOCO_GL before anything imports MuJoCo: the user's value if it can work, else
    with no display the first headless backend that loads, else rendering off, with the reason."""
    global choice
    value = os.environ.get(MUJOCO_GL, "").strip().lower()
    if value in OFF_VALUES:
        choice = Choice(None, "set in the environment", f"{MUJOCO_GL}={value} turns it off")
    elif value:
        choice = _users(value)
    elif has_display():
        choice = Choice("glfw", "MuJoCo's default")
    else:
        choice = _headless()
    os.environ[MUJOCO_GL] = choice.backend or OFF
    return choice


def _users(value: str) -> Choice:
    origin = "set in the environment"
    if value not in valid_backends():
        return Choice(None, origin, f"{MUJOCO_GL}={value} is not a backend MuJoCo knows "
                                    f"(use one of {', '.join(valid_backends())})")
    missing = loads(value) if value in LIBRARIES else None
    if missing:
        return Choice(None, origin, f"{MUJOCO_GL}={value}: {missing}; install "
                                    f"{PACKAGES[value]}, or unset {MUJOCO_GL}")
    return Choice(value, origin)


def _headless() -> Choice:
    origin = "lab's default without a display"
    missing = {}
    for backend in HEADLESS:
        missing[backend] = loads(backend)
        if missing[backend] is None:
            return Choice(backend, origin)
    why = "; ".join(f"{backend}: {reason}" for backend, reason in missing.items())
    return Choice(None, origin, f"no display, and no offscreen OpenGL library loads ({why}); "
                                f"on Debian/Ubuntu install {PACKAGES['egl']} (EGL)")


def backend() -> str:
    """What MuJoCo renders with in this process, for messages ("disable" when nothing)."""
    return choice.backend or OFF
