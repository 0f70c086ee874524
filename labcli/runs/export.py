"""`lab export onnx|jit`: write the Policy (normalizer folded in) and check it against torch."""

from __future__ import annotations

import contextlib
import enum
import io
import logging
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from labcli import files
from labcli.errors import LabError
from labcli.runs import rundir
from labcli.runs.play import LoadedPolicy, load

TOLERANCE = 1e-5
CHECK_STEPS = 64  # env steps of real observations to compare on, besides random ones


class Format(str, enum.Enum):
    onnx = "onnx"
    jit = "jit"


@dataclass
class ExportResult:
    path: Path
    metadata: Path
    max_abs_diff: float
    checked: int


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


def _export_onnx(policy: torch.nn.Module, example: torch.Tensor, path: Path) -> None:
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


def _export_jit(policy: torch.nn.Module, obs: torch.Tensor, path: Path) -> np.ndarray:
    """TorchScript is deprecated in favour of torch.export, but it is what C++ and ROS
    deployments load today; the warnings say nothing a user can act on."""
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.jit.save(torch.jit.trace(policy, obs[:2]), str(path))
        return torch.jit.load(str(path))(obs).numpy()


def _run_onnx(path: Path, obs: torch.Tensor) -> np.ndarray:
    import onnxruntime as ort

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return session.run(["actions"], {"obs": obs.numpy()})[0]


def export(fmt: Format | str, *, run_dir: Path | None = None, checkpoint: Path | None = None,
           task: str | None = None, framework: str | None = None,
           logs_dir: Path | None = None) -> ExportResult:
    fmt = Format(fmt)
    loaded = load(run_dir=run_dir, checkpoint=checkpoint, task=task, framework=framework,
                  logs_dir=logs_dir, num_envs=16)
    try:
        policy = loaded.policy.eval()
        obs = _check_observations(loaded)
        with torch.inference_mode():
            expected = policy(obs).numpy()
        run_dir = loaded.run.dir
        out_dir = files.real_dir(run_dir / rundir.EXPORTED, below=run_dir)
        path = out_dir / ("policy.onnx" if fmt is Format.onnx else "policy.pt")
        # Written and checked under a temporary name: the previous export survives a failed
        # check, a kill or a full disk, and a link at `path` is replaced, not followed.
        with files.staged(path, below=run_dir) as tmp:
            if fmt is Format.onnx:
                _export_onnx(policy, obs, tmp)
                got = _run_onnx(tmp, obs)
            else:
                got = _export_jit(policy, obs, tmp)
            diff = float(np.max(np.abs(got - expected)))
            if not diff < TOLERANCE:
                raise LabError(f"exported {path.name} differs from the torch policy by "
                               f"{diff:.2e} (tolerance {TOLERANCE:.0e}); nothing was written",
                               "please report this as a bug")
        metadata = out_dir / "policy.json"
        rundir.write_json(run_dir, f"{rundir.EXPORTED}/{metadata.name}",
                          _metadata(loaded, fmt, path, diff, len(obs)))
        return ExportResult(path, metadata, diff, len(obs))
    finally:
        loaded.env.close()


def _metadata(loaded: LoadedPolicy, fmt: Format, path: Path, diff: float,
              checked: int) -> dict:
    env = loaded.env
    return {
        "format": fmt.value,
        "file": path.name,
        "task": loaded.spec.name,
        "framework": loaded.framework.name,
        "checkpoint": loaded.checkpoint.path.name,
        "iteration": loaded.checkpoint.iteration,
        "input": {"name": "obs", "size": len(env.observation_names),
                  "names": env.observation_names, "dtype": "float32"},
        "output": {"name": "actions", "size": len(env.action_names), "names": env.action_names,
                   "low": -1.0, "high": 1.0, **env.action_scaling()},
        "normalizer_included": not isinstance(loaded.policy.normalizer, torch.nn.Identity),
        "control_dt": env.step_dt,
        "check": {"max_abs_diff": diff, "tolerance": TOLERANCE, "observations": checked},
    }
