"""lab: train, play and export RL policies for MuJoCo robots with the library you prefer."""

from labcli.envs.render import gl

# The one place the version is written: pyproject.toml reads it from here, and `lab --version`
# prints it without looking up the installed distribution.
__version__ = "0.1.0"

# MuJoCo reads MUJOCO_GL once, on its first import, and a value it cannot use fails that import.
# This package's __init__ runs before the body of any labcli module, whatever that module imports
# first: settle it here.
gl.settle()
