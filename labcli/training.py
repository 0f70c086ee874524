"""`lab train` as a library call: resolve config, make the run dir, build env and pipeline."""

from __future__ import annotations

import os
import shlex
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import torch
from rich.console import Console
from torch.utils.tensorboard import SummaryWriter

from labcli import __version__, config, metrics, plugins, runs, wrappers
from labcli import video as videos
from labcli.env import LabVecEnv
from labcli.errors import LabError
from labcli.framework import AgentConfig, Checkpoint, Framework
from labcli.progress import TrainProgress
from labcli.sim import WARP_INSTALL_HINT, default_backend
from labcli.task import TaskConfig, TaskSpec
from labcli.video import VideoSettings

LATEST = "latest"
STATES = ("running", "finished", "interrupted", "failed")


@dataclass
class TrainContext:
    """What a framework's `train` gets besides the env: config, run dir and the hooks that keep
    logging, progress, checkpoints and Ctrl-C the same for every library."""

    cfg: AgentConfig
    env: LabVecEnv
    framework: Framework
    run_dir: Path
    seed: int
    device: str
    progress: TrainProgress
    writer: SummaryWriter
    resume: Checkpoint | None = None
    iteration: int = 0
    steps: int = 0
    stop_requested: bool = False
    signal: int | None = None
    last_stats: dict[str, float] = field(default_factory=dict)
    saved_iteration: int = -1
    _clock: tuple[float, int] = (0.0, 0)

    def __post_init__(self) -> None:
        if self.resume is not None:
            self.iteration = self.saved_iteration = self.resume.iteration
        self._clock = (time.perf_counter(), self.steps)

    @property
    def start_iteration(self) -> int:
        return self.resume.iteration if self.resume else 0

    def end_iteration(self, iteration: int, steps: int, save: Callable[[Path], None],
                      scalars: dict[str, float] | None = None) -> bool:
        """Log the common figures, update progress, checkpoint when due. Returns True when
        training must stop now (Ctrl-C or SIGTERM); the checkpoint is already written then."""
        now = time.perf_counter()
        t0, s0 = self._clock
        steps_per_s = (steps - s0) / max(now - t0, 1e-9)
        self._clock = (now, steps)
        self.iteration, self.steps = iteration, steps
        stats = self.env.pop_stats()
        if stats:
            self.last_stats = stats
        figures = {**stats, metrics.STEPS_PER_S: steps_per_s, **(scalars or {})}
        for tag, value in figures.items():
            self.writer.add_scalar(tag, value, steps)
        self.progress.update(iteration, steps_per_s, self.last_stats.get(metrics.MEAN_RETURN),
                             self.last_stats.get(metrics.SUCCESS_RATE))
        due = iteration % self.cfg.save_interval == 0 or iteration >= self.cfg.max_iterations
        if due or self.stop_requested:
            self.save(save)
        return self.stop_requested

    def save(self, save: Callable[[Path], None]) -> None:
        """Write the checkpoint of the current iteration through a temporary file and a rename,
        so that a kill mid-write leaves the previous checkpoint as the latest complete one."""
        if self.saved_iteration == self.iteration:
            return
        target = self.framework.checkpoint_path(self.run_dir, self.iteration)
        tmp = target.with_name(f".tmp_{target.name}")
        save(tmp)
        os.replace(tmp, target)
        self.saved_iteration = self.iteration


@dataclass
class TrainOutcome:
    run: runs.Run
    summary: dict[str, Any]


def resolve_configs(spec: TaskSpec, fw: Framework, *, base: tuple[dict, dict] | None = None,
                    config_file: Path | None = None, overrides: Sequence[str] = (),
                    num_envs: int | None = None,
                    max_iterations: int | None = None) -> tuple[TaskConfig, AgentConfig]:
    """defaults ← task's defaults for this framework ← `base` (a resumed run) ← file ← --set ←
    the explicit flags."""
    defaults = spec.framework_defaults.get(fw.name, {})
    layers = [{"env": dict(defaults.get("env", {})), "agent": dict(defaults.get("agent", {}))}]
    if base is not None:
        layers.append({"env": base[0], "agent": base[1]})
    if config_file is not None:
        layers.append(config.load_file(config_file))
    layers.append(config.parse_set(overrides))
    flags: dict[str, dict[str, Any]] = {"env": {}, "agent": {}}
    if num_envs is not None:
        flags["env"]["num_envs"] = num_envs
    if max_iterations is not None:
        flags["agent"]["max_iterations"] = max_iterations
    layers.append(flags)
    env_cfg = config.build(spec.config, "env", [layer["env"] for layer in layers])
    agent_cfg = config.build(fw.agent_config, "agent", [layer["agent"] for layer in layers])
    return env_cfg, agent_cfg


def check_device(device: str | None, backend: str | None = None) -> str:
    """The torch device of the env and the learner; None picks CUDA for the warp backend (asked
    for, or the default where CUDA and MuJoCo Warp are usable), else the CPU."""
    if backend == "warp" and not torch.cuda.is_available():
        raise LabError("the warp backend needs CUDA, which torch cannot use here",
                       WARP_INSTALL_HINT)
    if device is None:
        wants_gpu = backend == "warp" or (backend is None and default_backend() == "warp")
        return "cuda" if wants_gpu else "cpu"
    try:
        dev = torch.device(device)
    except RuntimeError as exc:
        raise LabError(f"unknown device '{device}'", "use cpu, cuda or cuda:N") from exc
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise LabError(f"device '{device}' asked for, but CUDA is not available here",
                       "use --device cpu")
    return str(dev)


def find_checkpoint(value: str, logs_dir: Path, task: str, fw: Framework) -> tuple[runs.Run,
                                                                                    Checkpoint]:
    """`latest` (newest complete checkpoint of the newest run of task+framework) or a path."""
    if value == LATEST:
        for run in runs.find(logs_dir, task, fw.name):
            found = fw.checkpoints(run.dir)
            if found:
                return run, found[-1]
        raise LabError(f"no checkpoint of a {fw.name} run of '{task}' in {logs_dir}",
                       "train first, or pass --checkpoint PATH")
    path = Path(value)
    if path.is_dir():
        found = fw.checkpoints(path)
        if not found:
            raise LabError(f"{path} holds no {fw.name} checkpoint",
                           f"expected files like {fw.checkpoint_path(path, 100).name}")
        return runs.open_run(path), found[-1]
    if not path.is_file():
        raise LabError(f"checkpoint {path} does not exist", "pass a file, a run dir or 'latest'")
    match = [c for c in fw.checkpoints(path.parent) if c.path.name == path.name]
    if not match:
        raise LabError(f"{path.name} is not a {fw.name} checkpoint name",
                       f"expected a name like {fw.checkpoint_path(path.parent, 100).name}")
    return runs.open_run(path.parent), match[0]


def check_run_matches(run: runs.Run, task: str, framework: str) -> None:
    manifest = run.manifest()
    if manifest.get("task") != task or manifest.get("framework") != framework:
        raise LabError(
            f"run {run.dir} is a {manifest.get('framework')} run of '{manifest.get('task')}', "
            f"not a {framework} run of '{task}'",
            "pass a checkpoint of the same task and framework")


def _versions(fw_provider: plugins.Provider) -> dict[str, str]:
    out = {"lab": __version__}
    for dist in ("mujoco", "torch", "gymnasium", fw_provider.dist):
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            continue
    return out


@contextmanager
def _stop_on_signals(ctx: TrainContext) -> Iterator[None]:
    """First SIGINT/SIGTERM asks the framework to stop at the next step; a second one aborts."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return

    def handler(signum: int, frame: Any) -> None:
        if ctx.stop_requested:
            raise KeyboardInterrupt
        ctx.stop_requested = True
        ctx.signal = signum

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def train(task: str, framework: str, *, num_envs: int | None = None, seed: int = 0,
          max_iterations: int | None = None, device: str | None = None,
          backend: str | None = None,
          run_name: str | None = None, overrides: Sequence[str] = (),
          config_file: Path | None = None, checkpoint: str | None = None,
          logs_dir: Path | None = None, console: Console | None = None,
          command: Sequence[str] | None = None,
          video: VideoSettings | None = None) -> TrainOutcome:
    """Train `task` with `framework`; everything is validated before anything is written.
    With `video`, env 0 is recorded into <run dir>/videos/train/."""
    logs_dir = logs_dir or runs.default_logs_dir()
    console = console or Console(stderr=True)
    spec = plugins.get_task(task)
    fw = plugins.get_framework(framework)
    device = check_device(device, backend)
    if num_envs is not None and num_envs <= 0:
        raise LabError(f"--num-envs must be a positive integer, got {num_envs}")

    run: runs.Run | None = None
    resume: Checkpoint | None = None
    base = None
    if checkpoint is not None:
        run, resume = find_checkpoint(checkpoint, logs_dir, task, fw)
        check_run_matches(run, task, framework)
        base = (run.params(runs.ENV_PARAMS), run.params(runs.AGENT_PARAMS))
        seed = run.manifest().get("seed", seed)
    env_cfg, agent_cfg = resolve_configs(spec, fw, base=base, config_file=config_file,
                                         overrides=overrides, num_envs=num_envs,
                                         max_iterations=max_iterations)
    if resume is not None and resume.iteration >= agent_cfg.max_iterations:
        raise LabError(
            f"checkpoint {resume.path.name} is at iteration {resume.iteration}, and max_iterations"
            f" is {agent_cfg.max_iterations}", "pass a larger --max-iterations to train further")

    torch.manual_seed(seed)
    env = spec.make_env(env_cfg, backend=backend, device=device, seed=seed)
    try:
        if resume is not None:
            fw.load_policy(resume.path, env)  # a corrupt or mismatched checkpoint fails here
        wrappers.validate(_pipeline(fw, agent_cfg, video, None), fw.name)
        if video is not None:
            env.render()  # no GL, or an env that cannot render, fails before a run dir exists
        if run is None:
            run = runs.create(logs_dir, framework, task, run_name)
            runs.write_atomic(run.dir / runs.ENV_PARAMS, config.to_yaml(env_cfg))
            runs.write_atomic(run.dir / runs.AGENT_PARAMS, config.to_yaml(agent_cfg))
        else:
            runs.write_atomic(run.dir / runs.AGENT_PARAMS, config.to_yaml(agent_cfg))
        argv = list(command) if command is not None else ["lab", *sys.argv[1:]]
        runs.write_atomic(run.dir / runs.COMMAND, shlex.join(argv) + "\n")
        manifest = {
            "task": task, "framework": framework, "seed": seed, "device": device,
            "backend": env.backend, "num_envs": env.num_envs,
            "started": datetime.now().isoformat(timespec="seconds"), "pid": os.getpid(),
            "host": socket.gethostname(),
            "state": "running", "versions": _versions(plugins.registry().provider(
                "framework", framework)),
        }
        if resume is not None:
            manifest["resumed_from"] = resume.path.name
        runs.write_json(run.dir / runs.MANIFEST, manifest)
        pipeline = _pipeline(fw, agent_cfg, video, run.dir)
        return _run_training(fw, env, agent_cfg, run, resume, seed, device, pipeline, console)
    finally:
        env.close()


def _pipeline(fw: Framework, cfg: AgentConfig, video: VideoSettings | None,
              run_dir: Path | None) -> list[wrappers.Step]:
    """The env-stage wrappers lab adds, then the framework's adapter and wrappers. The video
    folder is known once the run dir exists; the order is checked before either."""
    env_stage = [video.step(videos.folder(run_dir or Path(), videos.TRAIN))] if video else []
    return [*env_stage, *fw.pipeline(cfg)]


def _run_training(fw: Framework, env: LabVecEnv, cfg: AgentConfig, run: runs.Run,
                  resume: Checkpoint | None, seed: int, device: str,
                  pipeline: list[wrappers.Step], console: Console) -> TrainOutcome:
    description = f"{fw.name} · {env.task_spec.name} · {env.num_envs} envs"
    writer = SummaryWriter(log_dir=str(run.dir))
    progress = TrainProgress(cfg.max_iterations, description, console,
                             start=resume.iteration if resume else 0)
    ctx = TrainContext(cfg=cfg, env=env, framework=fw, run_dir=run.dir, seed=seed,
                       device=device, progress=progress, writer=writer, resume=resume)
    wrapped = wrappers.apply(env, pipeline, fw.name)
    t0 = time.perf_counter()
    state = "failed"
    try:
        with progress, _stop_on_signals(ctx):
            fw.train(wrapped, ctx)
        state = "interrupted" if ctx.stop_requested else "finished"
    except KeyboardInterrupt:
        state = "interrupted"
        ctx.stop_requested = True
    finally:
        writer.close()
        summary = _summary(ctx, fw, run, state, time.perf_counter() - t0)
        runs.write_json(run.dir / runs.SUMMARY, summary)
        run.update_manifest(state=state)
        wrapped.close()  # env-stage wrappers write what they hold (a video cut short)
    if state == "interrupted":
        summary["signal"] = ctx.signal or signal.SIGINT
    return TrainOutcome(run, summary)


def _summary(ctx: TrainContext, fw: Framework, run: runs.Run, state: str,
             wall: float) -> dict[str, Any]:
    found = fw.checkpoints(run.dir)
    stats = ctx.last_stats
    return {
        "state": state,
        "iterations": ctx.iteration,
        "steps": ctx.steps,
        "wall_time_s": round(wall, 2),
        "mean_return": stats.get(metrics.MEAN_RETURN),
        "mean_episode_length": stats.get(metrics.MEAN_LENGTH),
        "success_rate": stats.get(metrics.SUCCESS_RATE),
        "checkpoint": found[-1].path.name if found else None,
        "finished": datetime.now().isoformat(timespec="seconds"),
    }
