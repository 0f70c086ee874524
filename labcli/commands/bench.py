"""`lab bench`."""

from __future__ import annotations

import json
from typing import Annotated

import typer

from labcli.commands.common import JsonOpt, SetOpt, TaskArg, complete_framework, out, table
from labcli.errors import LabError


def bench(
    task: TaskArg,
    num_envs: Annotated[str, typer.Option(help="Comma-separated env counts.")] = "16,256,1024",
    backend: Annotated[str | None, typer.Option(
        help="Simulation backend: cpu or warp [warp where CUDA is available].")] = None,
    device: Annotated[str | None, typer.Option(
        help="Torch device of the env [cuda with the warp backend, else cpu].")] = None,
    framework: Annotated[str | None, typer.Option(
        "--framework", "-f", help="Also time a short training run with this framework.",
        autocompletion=complete_framework)] = None,
    seconds: Annotated[float, typer.Option(
        help="Seconds per measurement (cpu backend: the env and MuJoCo's rollout take turns in "
             "4 windows of a quarter of it each).")] = 3.0,
    threads: Annotated[str | None, typer.Option(
        help="cpu backend: comma-separated counts of threads that step the physics, each "
             "measured beside MuJoCo's rollout on as many [the cores this process may use]."
    )] = None,
    set_: SetOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Measure env-steps/s of a task (random actions, resets included) and, with --framework,
    training steps/s.

    Example: lab bench --task cartpole --num-envs 16,256,1024 --framework rsl_rl
             lab bench --task humanoid --num-envs 1024,4096 --threads 2,4,8,16
             lab bench --task ant --num-envs 1024 --threads 16 --set env.compile=true
    """
    counts = _integers("--num-envs", num_envs, "16,256,1024")
    thread_counts = _integers("--threads", threads, "2,4,8,16") if threads is not None else []
    from labcli.runs import bench as benches

    rows = benches.bench(task, counts, backend=backend, device=device, framework=framework,
                         seconds=seconds, threads=thread_counts, overrides=set_ or [])
    if as_json:
        out().print_json(json.dumps([row.as_dict() for row in rows]))
        return
    columns = ["task", "backend", "threads", "envs", "env-steps/s"]
    with_rollout = any(row.rollout_steps_per_s for row in rows)
    if with_rollout:  # the raw physics of the same model: MuJoCo's rollout, or MuJoCo Warp
        physics = "mujoco_warp" if rows[0].backend == "warp" else "mujoco.rollout"
        columns += [physics, "ratio"]
    if framework:
        columns += ["framework", "training steps/s"]
    rows_table = table(*columns, title="lab bench")
    for row in rows:
        cells = [row.task, row.backend, str(row.threads or "-"), str(row.num_envs),
                 f"{row.env_steps_per_s:,.0f}"]
        if with_rollout:
            cells += ([f"{row.rollout_steps_per_s:,.0f}", f"{row.ratio_to_rollout:.2f}"]
                      if row.rollout_steps_per_s else ["-", "-"])
        if framework:
            cells += [row.framework, f"{row.train_steps_per_s:,.0f}"]
        rows_table.add_row(*cells)
    out().print(rows_table)


def _integers(option: str, text: str, example: str) -> list[int]:
    try:
        return [int(n) for n in text.split(",")]
    except ValueError:
        raise LabError(f"{option} '{text}' is not a list of integers",
                       f"e.g. {option} {example}") from None
