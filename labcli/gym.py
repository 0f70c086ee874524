"""lab's tasks from Python, and as gymnasium ids.

    import gymnasium as gym
    import labcli.gym                                   # registers "lab/<task>" for every task

    envs = gym.make_vec("lab/cartpole", num_envs=64)    # lab's batched env: torch tensors
    env = gym.make("lab/cartpole")                      # one env, NumPy, for single-env tools

    from labcli.gym import make_env
    envs = make_env("cartpole", 64, seed=1, episode_length_s=3.0)

`gym.make_vec("labcli.gym:lab/cartpole", ...)` imports this module itself. Keyword arguments of
`gym.make_vec` and `gym.make` are those of `make_env`: the task config's fields (as `--set
env.KEY=VALUE` sets them), `backend`, `device`, `seed`, `overrides`, `autoreset_mode` (not
`gym.make`'s: one env has no `num_envs` and no autoreset). A bad one is a ValueError or
TypeError naming it (also a `labcli.errors.LabError`), raised before anything is built.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym

from labcli.errors import LabTypeError
from labcli.plugins import registry

NAMESPACE = "lab"


def make_env(task: str, num_envs: int | None = None, *, backend: str | None = None,
             device: str | None = None, seed: int = 0, overrides: Sequence[str] = (),
             autoreset_mode: str = "same_step", **config: Any) -> Any:
    """The batched env of `task` (a `gymnasium.vector.VectorEnv` of torch tensors), as
    `lab train` builds it: the task's config defaults, then `config` (its fields by name), then
    `overrides` (`--set`-style "env.KEY=VALUE" strings), then `num_envs`. `backend` "cpu" or
    "warp" and `device` as `lab train --backend/--device` pick them (the warp backend on CUDA
    where it is usable); `seed` seeds its resets. `autoreset_mode`: "same_step" (the default:
    an ended env resets within the step, its last observation in `info["final_obs"]`) or
    "next_step" (it resets on the next step, as gymnasium's own vector envs do, which its
    observation wrappers need). A bad name or value is a LabError naming it (a ValueError or
    TypeError for `seed`, `overrides` and `autoreset_mode`)."""
    from labcli.envs.env import checked_seed
    from labcli.envs.make import make_env as build
    from labcli.runs import config as configs
    from labcli.runs.session import check_device

    seed = checked_seed(seed)
    if isinstance(overrides, (str, bytes)) or not all(isinstance(item, str)
                                                      for item in overrides):
        raise LabTypeError(f"overrides must be a list of 'KEY=VALUE' strings, got "
                           f"{overrides!r:.80}", "e.g. overrides=['env.episode_length_s=3']")
    spec = registry.get_task(task)
    layers = [config, configs.parse_set(_with_section(overrides))["env"]]
    if num_envs is not None:
        layers.append({"num_envs": num_envs})
    cfg = configs.build(spec.config_class, "env", layers)
    return build(spec, cfg, backend=backend, device=check_device(device, backend), seed=seed,
                 autoreset_mode=autoreset_mode)


def make_single(task: str, render_mode: str | None = None, **kwargs: Any) -> Any:
    """One env of `task` as a plain `gymnasium.Env` (NumPy), for `gym.make("lab/<task>")`."""
    from labcli.envs.single import SingleEnv

    for name in ("num_envs", "autoreset_mode"):  # make_env's, which one env has no use for
        if name in kwargs:
            raise LabTypeError(
                f"gym.make('{NAMESPACE}/{task}') makes one env, which takes no {name}: "
                f"gym.make_vec('{NAMESPACE}/{task}', {name}={kwargs[name]!r:.80}) makes a "
                "batched env")

    return SingleEnv(make_env(task, 1, autoreset_mode="next_step", **kwargs), render_mode)


def _with_section(overrides: Sequence[str]) -> list[str]:
    """`--set`-style overrides; the "env." prefix may be left out."""
    return [item if item.strip().startswith("env.") else f"env.{item.strip()}"
            for item in overrides]


def register() -> list[str]:
    """Register `lab/<task>` for every registered lab task not registered yet; returns the ids."""
    ids = []
    for name in registry.loaded().names(registry.TASK):
        env_id = f"{NAMESPACE}/{name}"
        if env_id not in gym.registry:
            gym.register(env_id, entry_point=f"{__name__}:make_single",
                         vector_entry_point=f"{__name__}:make_env", kwargs={"task": name})
        ids.append(env_id)
    return ids


register()
