"""`lab config show`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from labcli.commands.common import ConfigOpt, FrameworkArg, SetOpt, TaskArg, out


def show(
    task: TaskArg,
    framework: FrameworkArg,
    set_: SetOpt = None,
    config_file: ConfigOpt = None,
    backend: Annotated[str | None, typer.Option(
        help="Show the defaults `lab train --backend` picks: cpu, or warp (GPU scale) "
             "[warp where CUDA is available].")] = None,
    terrain: Annotated[Path | None, typer.Option(
        help="Also write a top view of the task's terrain (env.terrain), coloured by height, "
             "to this PNG.")] = None,
) -> None:
    """Print the fully resolved env and agent config as YAML, fit for `lab train --config`,
    after a comment that says which model the task uses (nothing is downloaded).

    Example: lab config show --task cartpole --framework sb3 --set agent.n_epochs=10 > my.yaml
    Example: lab config show --task humanoid --framework rsl_rl --backend warp
    Example: lab config show --task go1-rough --framework rsl_rl --terrain terrain.png
    """
    from labcli.envs import models
    from labcli.plugins import registry
    from labcli.runs import config
    from labcli.runs.plan import gpu_scale

    spec = registry.get_task(task)
    env_cfg, agent_cfg = config.resolve(
        spec, registry.get_framework(framework), config_file=config_file,
        overrides=set_ or [], gpu_scale=gpu_scale(backend, None))
    if terrain is not None:
        from labcli.runs import terrain_preview

        terrain_preview.write(spec, env_cfg, terrain)
    model = f"# model: {models.about_line(spec.model)}\n" if hasattr(spec, "model") else ""
    out().print(model + config.dump(env_cfg, agent_cfg), end="", highlight=False,
                soft_wrap=True, markup=False)
