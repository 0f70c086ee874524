"""`lab export onnx|jit`: write the Policy (normalizer folded in), check it against torch, and
describe it beside it (`policy.onnx.json`, `policy.pt.json`) and inside it (the ONNX model's
metadata, the TorchScript archive's extra file): what a deployment must feed it and do with its
output, and where it came from."""

from __future__ import annotations

import contextlib
import enum
import io
import json
import logging
import os
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from labcli import __version__, files
from labcli.envs import models
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.runs import loggers, rundir
from labcli.runs.play import LoadedPolicy, load

# Of the largest action checked, at least 1: float32 keeps 7 digits, and wide random
# observations through a normalizer's near-constant inputs drive actions to the clip (100),
# where torch's own float32 differs from float64 by ~1e-4.
TOLERANCE = 1e-5
CHECK_STEPS = 64  # env steps of real observations to compare on, besides random ones
METADATA_KEY = "lab"  # the ONNX metadata_props key, and the TorchScript extra file "lab.json"


class Format(str, enum.Enum):
    onnx = "onnx"
    jit = "jit"


@dataclass
class ExportResult:
    path: Path
    metadata: Path
    max_abs_diff: float
    checked: int
    # Why the export was not logged to the run's Weights & Biases run, where it has one.
    note: str | None = None


def check_tolerance(expected: np.ndarray) -> float:
    """The largest difference an export may show from the torch policy's actions `expected`."""
    return TOLERANCE * max(1.0, float(np.max(np.abs(expected))))


def _check_observations(loaded: LoadedPolicy) -> torch.Tensor:
    """Real observations from rolling the policy out, plus wide random ones."""
    env, policy = loaded.env, loaded.policy
    obs, _ = env.reset(seed=0)
    real = [obs]
    with torch.inference_mode():
        for _ in range(CHECK_STEPS - 1):
            obs, *_ = env.step(policy(obs))
            real.append(obs)
    real_t = torch.cat(real)
    gen = torch.Generator().manual_seed(0)
    scale = real_t.abs().amax(dim=0).clamp(min=1.0)
    random = torch.randn(256, real_t.shape[1], generator=gen) * scale
    return torch.cat([real_t, random]).float()


def _export_onnx(policy: torch.nn.Module, example: torch.Tensor, path: Path,
                 metadata: dict[str, Any]) -> None:
    batch = torch.export.Dim("batch")
    # The exporter narrates its passes, warns about torch internals and logs "torchvision is not
    # installed": nothing a user can act on.
    registration = logging.getLogger("torch.onnx._internal.exporter._registration")
    level = registration.level
    registration.setLevel(logging.ERROR)
    try:
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(policy, (example[:2],), str(path), input_names=["obs"],
                              output_names=["actions"], dynamic_shapes={"obs": {0: batch}},
                              external_data=False, verbose=False)
    finally:
        registration.setLevel(level)
    import onnx

    model = onnx.load(str(path))
    props = {METADATA_KEY: json.dumps(metadata)}
    if "deployment" in metadata:  # a robot's, also as mjlab's exports name it
        from labcli.envs.mdp import deployment

        props.update(deployment.mjlab_keys(
            metadata["deployment"], [o["name"] for o in metadata["input"]["observations"]]))
    onnx.helper.set_model_props(model, props)
    onnx.save(model, str(path))


def _export_jit(policy: torch.nn.Module, obs: torch.Tensor, path: Path,
                metadata: dict[str, Any]) -> np.ndarray:
    """TorchScript is deprecated in favour of torch.export, but it is what C++ and ROS
    deployments load today; the warnings say nothing a user can act on."""
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.jit.save(torch.jit.trace(policy, obs[:2]), str(path),
                       _extra_files={f"{METADATA_KEY}.json": json.dumps(metadata)})
        return torch.jit.load(str(path))(obs).numpy()


def _run_onnx(path: Path, obs: torch.Tensor) -> np.ndarray:
    import onnxruntime as ort

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return session.run(["actions"], {"obs": obs.numpy()})[0]


@contextlib.contextmanager
def _exporting(out_dir: Path) -> Iterator[None]:
    """One export of a run at a time (an advisory lock on its exported/ dir, which the OS
    releases when the process ends however): what an export killed before it could clean up
    left (`.tmp_policy.*`) is removed by the next."""
    try:
        import fcntl
    except ImportError:  # Windows: no flock; stale files stay until removed by hand
        yield
        return
    fd = os.open(out_dir, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | os.O_CLOEXEC)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        for stale in out_dir.glob(".tmp_policy*"):
            if stale.is_file() and not stale.is_symlink():
                stale.unlink(missing_ok=True)
        yield
    finally:
        os.close(fd)


def export(fmt: Format | str, *, run_dir: Path | None = None, checkpoint: Path | None = None,
           task: str | None = None, framework: str | None = None,
           logs_dir: Path | None = None, overrides: Sequence[str] = ()) -> ExportResult:
    """`overrides`: `--set`-style settings, as `lab play` takes them (`play.load`): the files a
    run's params name, which lab opens only when the user names them."""
    fmt = Format(fmt)
    loaded = load(run_dir=run_dir, checkpoint=checkpoint, task=task, framework=framework,
                  logs_dir=logs_dir, num_envs=16, overrides=overrides)
    try:
        policy = loaded.policy.eval()
        obs = _check_observations(loaded)
        with torch.inference_mode():
            expected = policy(obs).numpy()
        run_dir = loaded.run.dir
        out_dir = files.real_dir(run_dir / rundir.EXPORTED, below=run_dir)
        path = out_dir / ("policy.onnx" if fmt is Format.onnx else "policy.pt")
        metadata = describe(loaded, fmt, path)
        # A robot's model as its task steps it (actuators, gains, timestep): what a check in
        # plain MuJoCo (`lab sim2sim`, labcli.sim2sim) or a deployer's simulator loads.
        physics = out_dir / "policy.mjb" if "deployment" in metadata else None
        if physics is not None:
            metadata["mujoco_model"] = physics.name
        # Written and checked under a temporary name: the previous export survives a failed
        # check, a kill or a full disk, and a link at `path` is replaced, not followed.
        with _exporting(out_dir):
            with files.staged(path, below=run_dir) as tmp:
                if fmt is Format.onnx:
                    _export_onnx(policy, obs, tmp, metadata)
                    got = _run_onnx(tmp, obs)
                else:
                    got = _export_jit(policy, obs, tmp, metadata)
                diff = float(np.max(np.abs(got - expected)))
                tolerance = check_tolerance(expected)
                if not diff < tolerance:
                    raise LabError(f"exported {path.name} differs from the torch policy by "
                                   f"{diff:.2e} (tolerance {tolerance:.1e}); nothing was "
                                   "written", "please report this as a bug")
            if physics is not None:
                with files.staged(physics, below=run_dir) as tmp:
                    mujoco.mj_saveModel(loaded.env.task.model, str(tmp), None)
            metadata["check"] = {"max_abs_diff": diff, "tolerance": tolerance,
                                 "observations": len(obs)}
            beside = out_dir / f"{path.name}.json"
            rundir.write_json(run_dir, f"{rundir.EXPORTED}/{beside.name}", metadata)
        logged = loggers.log_export(run_dir, [p for p in (path, beside, physics) if p])
        return ExportResult(path, beside, diff, len(obs), logged)
    finally:
        loaded.env.close()


def describe(loaded: LoadedPolicy, fmt: Format, path: Path) -> dict[str, Any]:
    """The exported file's metadata: its input and output with units, conventions and the rule
    from action to actuator command (the task's own words), the timing, and its provenance
    (the robot model among it)."""
    env = loaded.env
    io_ = env.describe()
    library = loaded.framework.spec.library
    dists = ("mujoco", "torch", library, *(("onnx",) if fmt is Format.onnx else ()))
    model = getattr(loaded.spec, "model", None)  # a gym: task's is gymnasium's own
    return {
        "file": path.name,
        "format": fmt.value,
        "task": loaded.spec.name,
        **({"model": models.describe(model)} if model is not None else {}),
        "framework": loaded.framework.name,
        "run": loaded.run.dir.name,
        "checkpoint": loaded.checkpoint.path.name,
        "iteration": loaded.checkpoint.iteration,
        "exported": datetime.now().isoformat(timespec="seconds"),
        "versions": {"lab": __version__,
                     **{d: v for d in dists if d and (v := registry.installed(d))}},
        # Raw observations in: a normalizer the policy learned is part of the network.
        "input": {"name": "obs", "dtype": "float32", "shape": ["batch", len(io_["observations"])],
                  "observations": io_["observations"],
                  "normalizer_included": True,
                  "normalizer": ("folded into the network" if not isinstance(
                      loaded.policy.normalizer, torch.nn.Identity) else "none learned")},
        "output": {"name": "actions", "dtype": "float32", "shape": ["batch", len(io_["actions"])],
                   "range": io_["action_range"], "actions": io_["actions"],
                   "deterministic": True},
        "timing": {key: io_[key] for key in ("control_dt", "physics_dt", "decimation")
                   if key in io_},
        **({"deployment": io_["deployment"]} if "deployment" in io_ else {}),
    }
