"""Batched MuJoCo simulations behind one interface; tasks see only torch views of the state."""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import mujoco
import torch

from labcli.envs.config import UNSTABLE_VELOCITY
from labcli.errors import LabError

if TYPE_CHECKING:
    from labcli.envs.sim.chunks import ShardPhysics

BACKENDS = ("cpu", "warp")


class Sim:
    """`num_envs` copies of one MjModel. `qpos`, `qvel`, `ctrl` and `sensordata` are live
    `[num_envs, n]` views.

    `sensordata` holds the model's sensors as MuJoCo computes them inside its last physics step
    (before that step's integration, on both backends), and zeros for an env reset since: it is
    how a task reads what qpos and qvel do not hold (contact forces, joint wrenches, actuator
    forces, accelerations)."""

    model: mujoco.MjModel
    num_envs: int
    device: torch.device
    qpos: torch.Tensor
    qvel: torch.Tensor
    ctrl: torch.Tensor
    sensordata: torch.Tensor
    nthread: int | None = None  # CPU threads that step the physics, where a backend has them
    unstable_velocity: float = UNSTABLE_VELOCITY  # rad/s or m/s, past which `unstable` flags

    def step(self, nstep: int, controls: torch.Tensor | None = None,
             substep: Callable[[int], None] | None = None) -> None:
        """Advance every env `nstep` physics steps holding `ctrl`, or given `controls`
        (`[nstep, num_envs, nu]`, a tensor the caller keeps and rewrites), each physics step's;
        `ctrl` is then the last one's. With `substep`, it is called with k before physics step
        k and writes `ctrl` from the state then (torch code, on a GPU recorded into the step's
        CUDA graph); `controls` is then not read."""
        raise NotImplementedError

    def reset_to_defaults(self, mask: torch.Tensor) -> None:
        """Put the envs in `mask` back at the model's qpos0, zero velocity and time."""
        raise NotImplementedError

    def unstable(self) -> torch.Tensor:
        """Envs whose state diverged (non-finite or absurd velocities)."""
        # The largest speed, not `all` over a boolean matrix: the same answer (a NaN's max is
        # NaN, which is not below the limit) at 0.3-0.4 of the cost with 14-29 velocities.
        return ~(self.qvel.abs().amax(dim=1) < self.unstable_velocity)

    def any_unstable(self) -> bool:
        """Whether `unstable()` flags any env, read on the host (on a GPU, a wait for it)."""
        return bool(self.unstable().any())

    def model_field(self, name: str) -> torch.Tensor:
        """`[num_envs, ...]` values of an MjModel field that differs per env (friction, mass),
        one of the `per_env_fields` the sim was made with. Write into it in place, then call
        `model_changed(name, mask)` for the envs whose values changed."""
        raise LabError(f"model field '{name}' was not made per env",
                       "name it in the task's per_env_fields")

    def model_changed(self, name: str, mask: torch.Tensor) -> None:
        """Make the envs in `mask` step with their new `model_field(name)` values."""

    def pop_overflows(self) -> dict[str, float]:
        """Env steps, since the last call, in which a fixed-size buffer overflowed, by buffer
        name (MuJoCo Warp's contact and constraint buffers; such envs count as unstable)."""
        return {}

    def close(self) -> None:
        pass


def default_backend(device: str | None = None) -> str:
    """`warp` where the env lives on a CUDA device (or, with no device given, where CUDA is
    available) and MuJoCo Warp is installed; `cpu` otherwise."""
    on_gpu = torch.device(device).type == "cuda" if device else True
    return "warp" if on_gpu and torch.cuda.is_available() and _warp_installed() else "cpu"


def _warp_installed() -> bool:
    """Checked without importing them, so choosing a backend stays cheap."""
    return all(importlib.util.find_spec(name) for name in ("warp", "mujoco_warp"))


def make_sim(backend: str, model: mujoco.MjModel, num_envs: int, device: str,
             nthread: int | None = None, nconmax: int | None = None,
             njmax: int | None = None, per_env_fields: Sequence[str] = (),
             shard: ShardPhysics | None = None) -> Sim:
    """`shard`: the cpu backend's env shard that this sim steps (`labcli.envs.shards`)."""
    if backend == "cpu":
        from labcli.envs.sim.cpu import CpuSim

        if torch.device(device).type != "cpu":
            raise LabError(f"the cpu backend keeps its state on the CPU, not on '{device}'",
                           "use --device cpu, or --backend warp for a GPU")
        return CpuSim(model, num_envs, nthread, per_env_fields, shard)
    if backend == "warp":
        return _make_warp_sim(model, num_envs, device, nconmax, njmax, per_env_fields)
    raise LabError(f"unknown backend '{backend}'", f"choose one of: {', '.join(BACKENDS)}")


WARP_INSTALL_HINT = 'pip install -e ".[warp]" on a machine with an NVIDIA GPU, or use --backend cpu'


def _make_warp_sim(model: mujoco.MjModel, num_envs: int, device: str, nconmax: int | None,
                   njmax: int | None, per_env_fields: Sequence[str]) -> Sim:
    """MuJoCo Warp on CUDA; warp is imported here only, so `lab` runs without it."""
    if torch.device(device).type != "cuda":
        raise LabError(f"the warp backend keeps its state on a CUDA device, not on '{device}'",
                       "use --device cuda, or --backend cpu")
    if not torch.cuda.is_available():
        raise LabError("the warp backend needs CUDA, which torch cannot use here",
                       WARP_INSTALL_HINT)
    try:
        from labcli.envs.sim.warp import WarpSim
    except ImportError as exc:
        raise LabError(f"the warp backend needs MuJoCo Warp, which is not installed ({exc})",
                       WARP_INSTALL_HINT) from exc
    return WarpSim(model, num_envs, device, nconmax, njmax, per_env_fields)
