"""Commands that do not render never fail for want of a GL library, and `--video` without one is
one line. The GPU machine's case (NVIDIA's EGL driver, no `libEGL.so.1` loader) is simulated by
library files that cannot load, found first through LD_LIBRARY_PATH; a MUJOCO_GL that MuJoCo
refuses, or whose library is missing, likewise."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

TINY = ["--num-envs", "4", "--max-iterations", "1", "--set", "agent.num_steps_per_env=4"]
TRAIN = ["train", "--task", "cartpole", "--framework", "rsl_rl", *TINY]


@pytest.fixture(scope="module")
def broken_gl(tmp_path_factory) -> Path:
    """A folder of libEGL and libOSMesa files, under every name PyOpenGL tries, that cannot load."""
    folder = tmp_path_factory.mktemp("no_gl")
    for name in ("EGL", "OSMesa"):
        for suffix in ("", *(f".{i}" for i in range(10))):
            (folder / f"lib{name}.so{suffix}").write_text("not a library\n")
    return folder


def lab(*args: str, logs: Path, **env: str) -> subprocess.CompletedProcess:
    base = {k: v for k, v in os.environ.items()
            if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL", "PYOPENGL_PLATFORM")}
    return subprocess.run([sys.executable, "-m", "labcli", *args], capture_output=True,
                          text=True, timeout=300, env={**base, "LAB_LOGS_DIR": str(logs), **env})


def test_without_a_loadable_gl_library_everything_but_video_works(broken_gl, tmp_path):
    env = {"LD_LIBRARY_PATH": str(broken_gl)}
    for args in (["--version"], ["list"], ["runs"], TRAIN):
        result = lab(*args, logs=tmp_path, **env)
        assert result.returncode == 0, (args, result.stderr)
        assert "Traceback" not in result.stderr
    video = lab(*TRAIN, "--video", logs=tmp_path / "video", **env)
    assert video.returncode == 2
    error = video.stderr.splitlines()[-1]
    assert error.startswith("error: offscreen rendering is unavailable") and "libegl1" in error
    assert not (tmp_path / "video").exists()  # refused before a run dir was made
    info = lab("info", logs=tmp_path, **env, COLUMNS="300")
    assert info.returncode == 0
    rows = {line.split("  ")[0].strip(): line for line in info.stdout.splitlines()}
    assert "none" in rows["MUJOCO_GL"] and "unavailable" in rows["offscreen rendering (--video)"]


@pytest.mark.parametrize("value, problem", [("bogus", "not a backend MuJoCo knows"),
                                            ("osmesa", "no libOSMesa.so loads")])
def test_a_mujoco_gl_that_cannot_work_breaks_no_command_that_does_not_render(
        value, problem, broken_gl, tmp_path):
    env = {"MUJOCO_GL": value, "LD_LIBRARY_PATH": str(broken_gl)}
    for args in (["--help"], ["list"], ["info"]):
        result = lab(*args, logs=tmp_path, COLUMNS="300", **env)
        assert result.returncode == 0, (args, result.stderr)
    assert problem in lab("info", logs=tmp_path, COLUMNS="300", **env).stdout
    trained = lab(*TRAIN, logs=tmp_path, **env)
    assert trained.returncode == 0, trained.stderr
