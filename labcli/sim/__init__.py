"""Batched MuJoCo simulations behind one interface; tasks see only torch views of the state."""

from __future__ import annotations

import mujoco
import torch

from labcli.errors import LabError

BACKENDS = ("cpu", "warp")
# A velocity this large (or NaN) means the integrator diverged; such envs are reset.
UNSTABLE_VELOCITY = 1e6


class Sim:
    """`num_envs` copies of one MjModel. `qpos`, `qvel`, `ctrl` are live `[num_envs, n]` views."""

    model: mujoco.MjModel
    num_envs: int
    device: torch.device
    qpos: torch.Tensor
    qvel: torch.Tensor
    ctrl: torch.Tensor

    def step(self, nstep: int) -> None:
        """Advance every env `nstep` physics steps holding `ctrl`."""
        raise NotImplementedError

    def reset_to_defaults(self, mask: torch.Tensor) -> None:
        """Put the envs in `mask` back at the model's qpos0, zero velocity and time."""
        raise NotImplementedError

    def unstable(self) -> torch.Tensor:
        """Envs whose state diverged (non-finite or absurd velocities)."""
        return ~(self.qvel.abs() < UNSTABLE_VELOCITY).all(dim=1)

    def close(self) -> None:
        pass


def default_backend() -> str:
    return "warp" if torch.cuda.is_available() and _warp_installed() else "cpu"


def _warp_installed() -> bool:
    try:
        import mujoco_warp  # noqa: F401
    except ImportError:
        return False
    return True


def make_sim(backend: str, model: mujoco.MjModel, num_envs: int, device: str,
             nthread: int | None = None) -> Sim:
    if backend == "cpu":
        from labcli.sim.cpu import CpuSim

        if torch.device(device).type != "cpu":
            raise LabError(f"the cpu backend keeps its state on the CPU, not on '{device}'",
                           "use --device cpu, or --backend warp for a GPU")
        return CpuSim(model, num_envs, nthread)
    if backend == "warp":
        raise LabError("the warp backend is not available in this build", "use --backend cpu")
    raise LabError(f"unknown backend '{backend}'", f"choose one of: {', '.join(BACKENDS)}")
