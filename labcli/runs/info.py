"""`lab info`: versions and what this machine can do (rendering, CUDA, MuJoCo Warp); with a task
or a run, which model it uses."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco
import torch

from labcli import __version__
from labcli.envs import models
from labcli.envs.render import gl
from labcli.envs.render.scene import SceneRenderer
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.runs import recorded, rundir

PACKAGES = ("mujoco", "mujoco-menagerie", "torch", "gymnasium", "mujoco-warp", "warp-lang")
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


def model(task: str | None = None, run_dir: Path | None = None) -> dict[str, str]:
    """Which model a task uses, or a run recorded (and would play with), as name → value: a
    Menagerie robot's entry, package version and where its files are read from, found without
    downloading anything."""
    if run_dir is not None:
        run = rundir.open_run(run_dir)
        task_name, _ = run.identity()
        rows = {"run": str(run.dir), "task": task_name}
        return {**rows, **recorded.about(run, registry.get_task(task_name))}
    if task is None:
        return {}
    spec = registry.get_task(task)
    rows = {"task": spec.name}
    if hasattr(spec, "model"):
        return {**rows, **models.about(spec.model)}
    return {**rows, "model": spec.description}  # gym:<id>: gymnasium's own


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
