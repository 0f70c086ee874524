"""`--task gym:<id>`: the spec of a gymnasium env as a lab task. gymnasium itself is imported only
when such a task is asked for; its config is in labcli/envs/config.py, the env is
labcli/envs/gym_bridge.py."""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from labcli import refs
from labcli.errors import LabError, first_line

PREFIX = "gym:"
DESCRIPTION = "any registered gymnasium env with a bounded Box action space"
BACKEND = "gymnasium"

# rl_zoo3's PPO settings for MuJoCo continuous control (the PPO paper's: 2048 steps per update,
# 10 epochs, lr 3e-4, observations normalized, 1M steps), spread over 16 envs.
_ENVS, _STEPS, _ITERATIONS = 16, 128, 500
FRAMEWORK_DEFAULTS = {
    "sb3": {"env": {"num_envs": _ENVS}, "agent": {
        "max_iterations": _ITERATIONS, "save_interval": 50, "n_steps": _STEPS,
        "batch_size": 256, "n_epochs": 10, "learning_rate": 3e-4, "gamma": 0.99,
        "gae_lambda": 0.95, "clip_range": 0.2, "ent_coef": 0.0, "activation": "tanh",
        "normalize_obs": True}},
    "rsl_rl": {"env": {"num_envs": _ENVS}, "agent": {
        "max_iterations": _ITERATIONS, "save_interval": 50, "num_steps_per_env": _STEPS,
        "num_learning_epochs": 10, "num_mini_batches": 8, "learning_rate": 3e-4,
        "schedule": "fixed", "gamma": 0.99, "lam": 0.95, "entropy_coef": 0.0,
        "activation": "tanh"}},
    "skrl": {"env": {"num_envs": _ENVS}, "agent": {
        "max_iterations": _ITERATIONS, "save_interval": 50, "rollouts": _STEPS,
        "learning_epochs": 10, "mini_batches": 8, "learning_rate": 3e-4,
        "kl_adaptive_lr": False, "hidden_sizes": [64, 64], "activation": "tanh"}},
}

def is_gym_task(name: str) -> bool:
    return name.startswith(PREFIX)


@dataclass(frozen=True)
class GymTaskSpec:
    """A task made from a gymnasium id; what `plugins.get_task("gym:<id>")` returns."""

    name: str
    gym_id: str
    reward_threshold: float | None
    config: str = "labcli.envs.config:GymConfig"
    description: str = ""
    success: str = ""
    framework_defaults: Mapping[str, Mapping[str, Mapping[str, Any]]] = field(
        default_factory=lambda: FRAMEWORK_DEFAULTS)

    @property
    def config_class(self) -> type:
        return refs.resolve(self.config, f"task '{self.name}'")

    def lazy_refs(self) -> tuple[Any, ...]:
        return ()


def task_spec(name: str) -> GymTaskSpec:
    """The spec of `gym:<id>`; an unknown id is a LabError suggesting the closest one."""
    import gymnasium as gym

    gym_id = name[len(PREFIX):]
    try:
        env_spec = gym.spec(gym_id)
    except (gym.error.Error, ModuleNotFoundError) as exc:
        close = difflib.get_close_matches(gym_id, list(gym.registry), n=1)
        hint = f"did you mean 'gym:{close[0]}'? " if close else ""
        raise LabError(f"unknown gymnasium env '{gym_id}' ({first_line(exc)})",
                       hint + "see gymnasium.pprint_registry() for the registered ids") from None
    _check_importable(gym_id, env_spec.entry_point)
    threshold = env_spec.reward_threshold
    return GymTaskSpec(
        name=name, gym_id=gym_id, reward_threshold=threshold,
        description=f"gymnasium's {gym_id}",
        success=f"episode return ≥ {threshold:g} (the id's reward_threshold)"
        if threshold is not None else "")


def _check_importable(gym_id: str, entry_point: object) -> None:
    """Import the env's module now, so that one needing a package that is not installed (jax for
    gymnasium's phys2d and tabular envs, box2d for LunarLander) is one line, before any run."""
    from gymnasium.envs.registration import load_env_creator

    if not isinstance(entry_point, str):
        return
    try:
        load_env_creator(entry_point)
    except ImportError as exc:
        raise LabError(f"gymnasium env '{gym_id}' cannot be imported here: {first_line(exc)}",
                       "install the package that provides it, or pick another env") from None
    except Exception as exc:  # an env package broken in any other way: still one line
        raise LabError(f"gymnasium env '{gym_id}' cannot be loaded: {type(exc).__name__}: "
                       f"{first_line(exc)}") from None


def gym_ids() -> list[str]:
    """Every registered gymnasium id as a lab task name, for shell completion."""
    import gymnasium as gym

    return [PREFIX + gym_id for gym_id in gym.registry]
