"""Building the env of any task: lab's own batched env for a `TaskSpec`, gymnasium's vector env
behind lab's interface for `gym:<id>`."""

from __future__ import annotations

from typing import Any

from labcli.envs.gym_spec import BACKEND, GymTaskSpec
from labcli.envs.spec import TaskSpec
from labcli.errors import LabError, LabValueError


def make_env(spec: TaskSpec | GymTaskSpec, cfg: Any, *, backend: str | None = None,
             device: str = "cpu", seed: int = 0, autoreset_mode: Any = "same_step") -> Any:
    """The batched env of `spec` under the validated config `cfg` (`spec.config_class`);
    `autoreset_mode` "same_step" or "next_step" (lab's own tasks)."""
    if isinstance(spec, GymTaskSpec):
        if str(getattr(autoreset_mode, "value", autoreset_mode)).replace("_", "").lower() \
                != "samestep":
            raise LabValueError(f"gymnasium tasks reset in the same step, not as "
                                f"{autoreset_mode!r}", "leave autoreset_mode out for gym: tasks")
        # gymnasium's MuJoCo envs step MuJoCo's C engine: "cpu" is what they are, "warp" not.
        if backend not in (None, "cpu", BACKEND):
            raise LabError(f"gymnasium tasks step in gymnasium on the CPU, not on the "
                           f"'{backend}' backend", "leave --backend out for gym: tasks")
        from labcli.envs.gym_bridge import GymVecEnv

        return GymVecEnv(spec, cfg, device=device, seed=seed)
    from labcli.envs.env import LabVecEnv
    from labcli.envs.shards import ShardedVecEnv, shard_count
    from labcli.envs.sim import default_backend

    if (backend or default_backend(device)) == "cpu" and device == "cpu" \
            and shard_count(cfg.num_envs, cfg.threads) > 1:
        return ShardedVecEnv(spec, cfg, seed=seed, autoreset_mode=autoreset_mode)
    return LabVecEnv(spec, cfg, backend=backend, device=device, seed=seed,
                     autoreset_mode=autoreset_mode)
