"""`lab info`: versions and what this machine can do (rendering, CUDA, MuJoCo Warp)."""

from __future__ import annotations

import importlib.util

import mujoco
import torch

from labcli import __version__
from labcli.envs.render import gl
from labcli.envs.render.scene import SceneRenderer
from labcli.errors import LabError
from labcli.plugins import registry

PACKAGES = ("mujoco", "torch", "gymnasium", "mujoco-warp", "warp-lang")
# One sphere: the smallest scene whose rendering exercises the whole GL path.
PROBE_MODEL = '<mujoco><worldbody><geom type="sphere" size="0.1"/></worldbody></mujoco>'


def collect() -> dict[str, str]:
    """What `lab info` prints, as name → value."""
    out = {"lab": __version__}
    for dist in PACKAGES:
        out[dist] = registry.installed(dist) or "not installed"
    reg = registry.loaded()
    for name in reg.names(registry.FRAMEWORK):
        library = reg.get(registry.FRAMEWORK, name).library
        found = library and (registry.installed(library) or "not installed")
        out[f"framework {name}"] = (f"{library} {found}, " if library else "") + \
            f"plugin from {reg.provider(registry.FRAMEWORK, name)}"
    out["MUJOCO_GL"] = f"{gl.choice.backend or 'none'} ({gl.choice.origin})"
    rendering = _rendering()
    out["offscreen rendering (--video)"] = rendering
    out["display (--viewer)"] = "yes" if gl.has_display() else "no"
    out["CUDA"] = (f"yes, {torch.cuda.device_count()} device(s): {torch.cuda.get_device_name(0)}"
                   if torch.cuda.is_available() else "no")
    out["mujoco_warp"] = _warp()
    return out


def _rendering() -> str:
    renderer = SceneRenderer(mujoco.MjModel.from_xml_string(PROBE_MODEL), 8, 8)
    try:
        data = renderer.data
        renderer.render(torch.as_tensor(data.qpos), torch.as_tensor(data.qvel))
        return "works"
    except LabError as exc:
        return f"fails: {exc.message}"
    finally:
        renderer.close()


def _warp() -> str:
    if importlib.util.find_spec("mujoco_warp") is None:
        return "not installed"
    if not torch.cuda.is_available():
        return "installed, not usable: no CUDA"
    try:
        import mujoco_warp  # noqa: F401
    except Exception as exc:  # a broken CUDA or warp install shows here, not mid-training
        return f"installed, fails to import: {type(exc).__name__}: {exc}"
    return "usable (--backend warp)"
