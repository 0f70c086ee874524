"""`lab config show --terrain`: a task's terrain, built as training builds it, drawn from
above."""

from __future__ import annotations

from pathlib import Path

from labcli.envs.config import TaskConfig
from labcli.envs.spec import TaskSpec
from labcli.errors import LabError


def write(spec: TaskSpec, env_cfg: TaskConfig, output: Path) -> None:
    """The PNG of `spec`'s terrain under `env_cfg` (its --set settings included), from the
    model the task builds."""
    if output.suffix.lower() != ".png":
        raise LabError(f"--terrain {output}: lab writes PNG images", "name a file ending in .png")
    terrain = getattr(env_cfg, "terrain", None)
    if terrain is None:
        raise LabError(f"task '{spec.name}' has no terrain (env.terrain)",
                       "name a task with one (go1-rough, g1-rough), or give env.terrain")
    from labcli.envs.mdp import terrain_model

    model = spec.task_class.build_model(env_cfg, spec.model)
    terrain_model.save_preview(model, terrain, output)
