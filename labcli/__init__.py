"""lab: train, play and export RL policies for MuJoCo robots with the library you prefer."""

from importlib.metadata import PackageNotFoundError, version

from labcli.envs.render import gl

gl.settle()  # before any module imports mujoco, which reads MUJOCO_GL on import

try:
    __version__ = version("lab")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"
