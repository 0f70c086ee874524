# labcli settles MUJOCO_GL on import (egl without a display), and MuJoCo reads it once, on its own
# first import: import labcli before any test module imports mujoco, so rendering tests see it.
import labcli  # noqa: F401
