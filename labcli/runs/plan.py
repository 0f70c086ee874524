"""What a `lab train` is about to do, worked out from specs, configs and the run dir alone (no
torch, no learning library): so that bad input fails at once, and a valid command says in its
first line what it will do before the seconds of importing and building start."""

from __future__ import annotations

import ctypes
import importlib.util
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from labcli.errors import LabError
from labcli.plugins import registry
from labcli.plugins.config import AgentConfig
from labcli.plugins.framework import Checkpoint, FrameworkSpec
from labcli.runs import checkpoints, config, loggers, recorded, rundir
from labcli.runs.video import VideoSettings


@dataclass
class TrainPlan:
    spec: Any  # a TaskSpec, or the spec of a gym: task
    framework: FrameworkSpec
    env_cfg: Any
    agent_cfg: AgentConfig
    logs_dir: Path
    device: str | None
    backend: str | None
    run_name: str | None = None
    run: rundir.Run | None = None  # the run a resume continues
    resume: Checkpoint | None = None
    video: VideoSettings | None = None
    # What a resume changes: {"agent.learning_rate": (old, new), ...}, all of them resumable.
    changes: dict[str, tuple[Any, Any]] = field(default_factory=dict)
    ranks: int = 1  # data-parallel processes, each with env_cfg.num_envs envs
    # Lines to say after the plan's (a resumed run's model changed since it was recorded).
    warnings: list[str] = field(default_factory=list)
    logger: str = "tensorboard"  # where figures go besides TensorBoard (labcli.runs.loggers)

    @property
    def write_dir(self) -> Path:
        """Where the run writes: the resumed run's dir, or the folder a new one goes into."""
        if self.run is not None:
            return self.run.dir
        return self.logs_dir / self.framework.name / self.spec.name

    def describe(self) -> str:
        """One line: what is about to be trained, how big, and where a resume goes on."""
        n, seed = self.env_cfg.num_envs, self.agent_cfg.seed
        envs, seeds = f"{n} envs", f"seed {seed}"
        if self.ranks > 1:
            envs = f"{self.ranks} ranks × {n} envs ({self.ranks * n} in all)"
            seeds = f"seeds {seed} to {seed + self.ranks - 1}"
        what = f"{self.spec.name} with {self.framework.name}: {envs}, {seeds}"
        if self.resume is None:
            return f"train {what}, {self.agent_cfg.max_iterations} iterations"
        changed = "".join(f", {key} {old!r} -> {new!r}"
                          for key, (old, new) in self.changes.items()
                          if key not in ("agent.max_iterations", "env.num_envs"))
        return (f"resume {self.run.dir} from {self.resume.path.name}: {what}, iterations "
                f"{self.resume.iteration + 1} to {self.agent_cfg.max_iterations}{changed}")


def gpu_scale(backend: str | None, device: str | None) -> bool:
    """Whether the run will step on the warp backend, asked or picked by default (CUDA and
    MuJoCo Warp usable): its task defaults are the GPU-scale ones. torch is imported only where
    MuJoCo Warp is installed, NVIDIA's driver loads and nothing was asked."""
    if backend is not None:
        return backend == "warp"
    if device is not None:
        return device.startswith("cuda")
    if importlib.util.find_spec("mujoco_warp") is None or not cuda_driver_loads():
        return False
    from labcli.envs.sim import default_backend

    return default_backend() == "warp"


def cuda_driver_loads() -> bool:
    """Whether NVIDIA's driver library loads: without it no GPU is usable, and saying so takes
    milliseconds where asking torch takes the second of importing it."""
    try:
        ctypes.CDLL("nvcuda.dll" if sys.platform == "win32" else "libcuda.so.1")
    except OSError:
        return False
    return True


def plan(task: str, framework: str, *, num_envs: int | None = None, seed: int | None = None,
         max_iterations: int | None = None, device: str | None = None,
         backend: str | None = None, run_name: str | None = None,
         overrides: Sequence[str] = (), config_file: Path | None = None,
         checkpoint: str | None = None, logs_dir: Path | None = None,
         video: VideoSettings | None = None, ranks: int = 1,
         logger: str = "tensorboard") -> TrainPlan:
    """Resolve the task, the framework, the checkpoint to resume and the configs, or raise the
    LabError that says what is wrong. `ranks` > 1: one rank's share of a data-parallel run."""
    logs_dir = logs_dir or rundir.default_logs_dir()
    spec = registry.get_task(task)
    fw = registry.get_framework(framework)
    loggers.check(logger)
    if ranks > 1 and not fw.data_parallel:
        reg = registry.loaded()
        able = [name for name in reg.names(registry.FRAMEWORK)
                if reg.get(registry.FRAMEWORK, name).data_parallel]
        raise LabError(f"framework '{fw.name}' has no data-parallel training ({ranks} ranks "
                       "asked for)", f"train it in one process, or use {' or '.join(able)}")
    if num_envs is not None and num_envs <= 0:
        raise LabError(f"--num-envs must be a positive integer, got {num_envs}")
    if run_name is not None:
        rundir.check_run_name(run_name)
    run = resume = base = warning = None
    if checkpoint is not None:
        run, resume = checkpoints.find(checkpoint, logs_dir, task, fw)
        checkpoints.check_run_matches(run, task, framework)
        # The model the run trained on, whatever the task names now.
        spec, warning = recorded.spec_of(run, spec)
        base = (run.params(rundir.ENV_PARAMS), run.params(rundir.AGENT_PARAMS))
        # What this command sets: the run's settings may name a file only where it does too.
        given = [config.parse_set(overrides)]
        if config_file is not None:
            given.append(config.load_file(config_file))
        config.check_saved(spec.config_class, "env", run.dir / rundir.ENV_PARAMS, base[0],
                           [layer["env"] for layer in given])
        config.check_saved(fw.agent_config_class, "agent", run.dir / rundir.AGENT_PARAMS,
                           base[1], [layer["agent"] for layer in given])
    env_cfg, agent_cfg = config.resolve(spec, fw, base=base, config_file=config_file,
                                        overrides=overrides, num_envs=num_envs,
                                        max_iterations=max_iterations, seed=seed,
                                        gpu_scale=gpu_scale(backend, device))
    changes = {}
    if base is not None:
        saved_env = config.build(spec.config_class, "env", [base[0]])
        saved_agent = config.build(fw.agent_config_class, "agent", [base[1]])
        changes = {**config.changes(saved_env, env_cfg, "env"),
                   **config.changes(saved_agent, agent_cfg, "agent")}
        config.check_resumable(resume.path.name, changes, spec.config_class,
                               fw.agent_config_class)
    agent_cfg.check(env_cfg.num_envs)
    if resume is not None and resume.iteration >= agent_cfg.max_iterations:
        raise LabError(
            f"checkpoint {resume.path.name} is at iteration {resume.iteration}, and max_iterations"
            f" is {agent_cfg.max_iterations}", "pass a larger --max-iterations to train further")
    return TrainPlan(spec, fw, env_cfg, agent_cfg, logs_dir, device, backend, run_name, run,
                     resume, video, changes, ranks, [warning] if warning else [], logger)
