"""`lab train` as a library call: resolve config, make the run dir, build env and pipeline."""

from __future__ import annotations

import math
import os
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import torch
from rich.console import Console
from torch import nn
from torch.utils.tensorboard import SummaryWriter

from labcli import (
    __version__,
    config,
    interrupt,
    metrics,
    mjwarnings,
    plugins,
    runs,
    snapshot,
    wrappers,
)
from labcli import video as videos
from labcli.env import LabVecEnv
from labcli.errors import Interrupted, LabError, TrainingDiverged
from labcli.framework import AgentConfig, Checkpoint, Framework
from labcli.lastgood import LastGood
from labcli.progress import TrainProgress
from labcli.sim import WARP_INSTALL_HINT, default_backend
from labcli.task import TaskConfig, TaskSpec
from labcli.video import VideoSettings

LATEST = "latest"
NONFINITE_NETWORKS = "its update left non-finite values (NaN or inf) in the agent's networks"
DIVERGED_HINT = ("lower agent.learning_rate (or raise its clipping) and resume from the last good "
                 "checkpoint with --checkpoint")


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
    resume_state: dict[str, Any] | None = None
    stop: interrupt.StopRequest = field(default_factory=interrupt.StopRequest)
    mujoco_warnings: mjwarnings.WarningCounter = field(default_factory=mjwarnings.WarningCounter)
    iteration: int = 0
    steps: int = 0
    last_stats: dict[str, float] = field(default_factory=dict)
    saved_iteration: int = -1
    # The env and random generators at the end of the last iteration, saved with its checkpoint.
    _boundary: dict[str, Any] | None = None
    _told_mujoco_warnings: bool = False
    _networks: list[nn.Module] = field(default_factory=list)
    last_good: LastGood = field(init=False)
    _clock: tuple[float, int] = (0.0, 0)

    def __post_init__(self) -> None:
        if self.resume is not None:
            self.iteration = self.saved_iteration = self.resume.iteration
        if self.resume_state is not None:
            self.steps = self.resume_state["steps"]
        self._clock = (time.perf_counter(), self.steps)
        self.last_good = LastGood(self.run_dir, self.framework)
        self.last_good.discard()  # left by a killed run: not this run's, never to be committed

    @property
    def start_iteration(self) -> int:
        return self.resume.iteration if self.resume else 0

    @property
    def stop_requested(self) -> bool:
        """SIGINT or SIGTERM arrived: stop at the next env step, the checkpoint is taken care of."""
        return self.stop.requested

    def restore_rng(self) -> None:
        """On resume, put the random generators back where the checkpoint's iteration left them.
        A framework calls this once its agent is built (building draws random weights), just
        before the first rollout, so that a resumed run samples what an unbroken one would."""
        if self.resume_state is not None:
            snapshot.set_rng_state(self.resume_state["rng"])

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
        bad = stats.get(metrics.NONFINITE_ACTIONS, 0)
        if bad:  # the candidate, which acted in this rollout, is bad
            raise self._diverged(iteration, "the policy emitted non-finite actions (NaN or inf) "
                                 f"in {bad:.0f} env steps", candidate_proven=False)
        if not self.networks_finite():  # the candidate acted well; this update broke it
            raise self._diverged(iteration, NONFINITE_NETWORKS, candidate_proven=True)
        self.last_good.promote()
        self._boundary = {"env": self.env.get_state(), "rng": snapshot.rng_state(),
                          "iteration": iteration, "steps": steps}
        self.last_good.keep(iteration, self._boundary, save)
        figures = {**stats, metrics.STEPS_PER_S: steps_per_s,
                   metrics.MUJOCO_WARNINGS: self._pop_mujoco_warnings(), **(scalars or {})}
        for tag, value in figures.items():
            self.writer.add_scalar(tag, value, steps)
        self.progress.update(iteration, steps_per_s, self.last_stats.get(metrics.MEAN_RETURN),
                             self.last_stats.get(metrics.SUCCESS_RATE))
        due = iteration % self.cfg.save_interval == 0 or iteration >= self.cfg.max_iterations
        if due or self.stop_requested:
            self.save(save)
        return self.stop_requested

    def watch(self, *networks: nn.Module) -> None:
        """The agent's networks: after each update they are checked for NaN and inf, so that a
        diverged update stops training with a clear message, not a library's traceback."""
        self._networks.extend(networks)

    def networks_finite(self) -> bool:
        return all(_finite(module) for module in self._networks)

    def failed_on_networks(self, exc: Exception) -> TrainingDiverged:
        """For a library that failed in an update on the NaN it produced: the candidate is
        proven if it acted finitely in the rollout before."""
        acted_finitely = not self.env.pop_stats().get(metrics.NONFINITE_ACTIONS, 0)
        error = self._diverged(self.iteration + 1, NONFINITE_NETWORKS, acted_finitely)
        error.message += f" ({self.framework.name} failed on them: {type(exc).__name__}: {exc})"
        return error

    def _diverged(self, iteration: int, what: str, candidate_proven: bool) -> TrainingDiverged:
        self.last_good.commit(candidate_proven)
        return TrainingDiverged(f"iteration {iteration}: {what}; training stopped. "
                                f"{self._last_good()}", DIVERGED_HINT)

    def _pop_mujoco_warnings(self) -> int:
        count = self.mujoco_warnings.pop()
        if count and not self._told_mujoco_warnings:
            self._told_mujoco_warnings = True
            self.progress.console.print(
                f"note: MuJoCo warns '{self.mujoco_warnings.first}'; the envs concerned are "
                f"reset and counted ({metrics.INSTABILITIES}), and further warnings in "
                f"{metrics.MUJOCO_WARNINGS}", highlight=False, soft_wrap=True)
        return count

    def save(self, save: Callable[[Path], None]) -> None:
        """Write the checkpoint of the current iteration through a temporary file and a rename,
        so that a kill mid-write leaves the previous checkpoint as the latest complete one. The
        env and generator state goes first: a checkpoint's presence implies its state's. A
        policy that acts with NaN is never renamed into place: it stops training instead."""
        if self.saved_iteration == self.iteration:
            return
        if self._boundary is not None and self._boundary["iteration"] == self.iteration:
            snapshot.save(snapshot.path_of(self.run_dir, self.iteration), self._boundary)
        target = self.framework.checkpoint_path(self.run_dir, self.iteration)
        tmp = target.with_name(f".tmp_{target.name}")
        save(tmp)
        if not self._acts_finitely(tmp):
            tmp.unlink()
            raise self._diverged(self.iteration, "the policy's actions are not finite (NaN or "
                                 "inf) after this iteration's update", candidate_proven=False)
        os.replace(tmp, target)
        self.saved_iteration = self.iteration

    def _acts_finitely(self, checkpoint: Path) -> bool:
        # Loading builds networks, which draws random weights (SB3's load even reseeds every
        # generator): the run must go on with the numbers it would have drawn without the check.
        rng = snapshot.rng_state()
        try:
            # Policies load onto the CPU (portable checkpoints); the env may be on a GPU.
            policy = self.framework.load_policy(checkpoint, self.env).to(self.env.device)
            with torch.no_grad():
                return bool(torch.isfinite(policy(self.env.observations())).all())
        finally:
            snapshot.set_rng_state(rng)

    def _last_good(self) -> str:
        found = self.framework.checkpoints(self.run_dir)
        if not found:
            return "No checkpoint was written before it."
        return f"The last good checkpoint is {found[-1].path.name}."


def _finite(module: nn.Module) -> bool:
    return all(bool(torch.isfinite(t).all()) for t in module.state_dict().values()
               if t.is_floating_point())


@dataclass
class TrainOutcome:
    run: runs.Run
    summary: dict[str, Any]


def resolve_configs(spec: TaskSpec, fw: Framework, *, base: tuple[dict, dict] | None = None,
                    config_file: Path | None = None, overrides: Sequence[str] = (),
                    num_envs: int | None = None, max_iterations: int | None = None,
                    seed: int | None = None) -> tuple[TaskConfig, AgentConfig]:
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
    if seed is not None:
        flags["agent"]["seed"] = seed
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
    """`latest` (newest complete checkpoint of the newest run of task+framework) or a path; a
    run dir gives its newest complete checkpoint."""
    if value == LATEST:
        for run in runs.find(logs_dir, task, fw.name):
            found = fw.latest_checkpoint(run.dir)
            if found is not None:
                return run, found
        raise LabError(f"no complete checkpoint of a {fw.name} run of '{task}' in {logs_dir}",
                       "train first, or pass --checkpoint PATH")
    path = Path(value)
    if path.is_dir():
        found = fw.latest_checkpoint(path)
        if found is None:
            broken = ", ".join(c.path.name for c in fw.checkpoints(path))
            raise LabError(f"{path} holds no complete {fw.name} checkpoint"
                           + (f" ({broken}: truncated or damaged)" if broken else ""),
                           f"expected files like {fw.checkpoint_path(path, 100).name}")
        return runs.open_run(path), found
    if not path.is_file():
        raise LabError(f"checkpoint {path} does not exist", "pass a file, a run dir or 'latest'")
    match = [c for c in fw.checkpoints(path.parent) if c.path.name == path.name]
    if not match:
        raise LabError(f"{path.name} is not a {fw.name} checkpoint name",
                       f"expected a name like {fw.checkpoint_path(path.parent, 100).name}")
    if not fw.checkpoint_complete(path):
        raise LabError(f"checkpoint {path} is incomplete (truncated or damaged)",
                       "pick another checkpoint, or pass the run dir for its newest complete one")
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


def train(task: str, framework: str, *, num_envs: int | None = None, seed: int | None = None,
          max_iterations: int | None = None, device: str | None = None,
          backend: str | None = None,
          run_name: str | None = None, overrides: Sequence[str] = (),
          config_file: Path | None = None, checkpoint: str | None = None,
          logs_dir: Path | None = None, console: Console | None = None,
          command: Sequence[str] | None = None,
          video: VideoSettings | None = None) -> TrainOutcome:
    """Train `task` with `framework`; everything is validated before anything is written.
    With `video`, env 0 is recorded into <run dir>/videos/train/.
    SIGINT/SIGTERM from the first line on stop it cleanly: before the run dir exists, with
    nothing written (Interrupted); after, with a checkpoint and state 'interrupted'."""
    with interrupt.deferred() as stop:
        try:
            return _train(stop, task, framework, num_envs=num_envs, seed=seed,
                          max_iterations=max_iterations, device=device, backend=backend,
                          run_name=run_name, overrides=overrides, config_file=config_file,
                          checkpoint=checkpoint, logs_dir=logs_dir, console=console,
                          command=command, video=video)
        except KeyboardInterrupt:  # a second signal before the run dir existed
            stop.request()
            raise _interrupted_before_run(stop) from None


def _resume_state(run: runs.Run, resume: Checkpoint, env_cfg: TaskConfig,
                  console: Console) -> dict[str, Any] | None:
    """The env and generator state saved with `resume`, or None (with a note saying what that
    changes) when there is none or it cannot apply."""
    state = snapshot.load(snapshot.path_of(run.dir, resume.iteration))
    if state is None:
        console.print(f"note: {resume.path.name} has no saved env and random-generator state; "
                      "the resumed run starts new episodes", highlight=False)
    elif state["env"] is None:
        console.print(f"note: the env of {resume.path.name} cannot save its episodes; the "
                      "resumed run starts new ones", highlight=False)
    elif state["env"]["qpos"].shape[0] != env_cfg.num_envs:
        console.print(f"note: {resume.path.name} was saved with {state['env']['qpos'].shape[0]} "
                      f"envs, not {env_cfg.num_envs}; the resumed run starts new episodes",
                      highlight=False)
        return None
    return state


def _interrupted_before_run(stop: interrupt.StopRequest) -> Interrupted:
    return Interrupted(f"interrupted by {stop.name} before the run started; nothing was written",
                       stop.exit_code)


def _train(stop: interrupt.StopRequest, task: str, framework: str, *, num_envs: int | None,
           seed: int | None, max_iterations: int | None, device: str | None, backend: str | None,
           run_name: str | None, overrides: Sequence[str], config_file: Path | None,
           checkpoint: str | None, logs_dir: Path | None, console: Console | None,
           command: Sequence[str] | None, video: VideoSettings | None) -> TrainOutcome:
    logs_dir = logs_dir or runs.default_logs_dir()
    console = console or Console(stderr=True)
    spec = plugins.get_task(task)
    fw = plugins.get_framework(framework)
    for failure in plugins.registry().failures:  # what they provide is missing: say so
        console.print(f"warning: plugin '{failure.plugin}' ({failure.provider}) failed to load: "
                      f"{failure.error}", highlight=False, soft_wrap=True, markup=False)
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
        config.check_saved(spec.config, "env", run.dir / runs.ENV_PARAMS, base[0])
        config.check_saved(fw.agent_config, "agent", run.dir / runs.AGENT_PARAMS, base[1])
    env_cfg, agent_cfg = resolve_configs(spec, fw, base=base, config_file=config_file,
                                         overrides=overrides, num_envs=num_envs,
                                         max_iterations=max_iterations, seed=seed)
    if resume is not None and resume.iteration >= agent_cfg.max_iterations:
        raise LabError(
            f"checkpoint {resume.path.name} is at iteration {resume.iteration}, and max_iterations"
            f" is {agent_cfg.max_iterations}", "pass a larger --max-iterations to train further")
    # Before any simulation: a run that cannot be written must not cost a minute of start-up.
    runs.check_writable(run.dir if run is not None else logs_dir / framework / task)

    snapshot.seed_all(agent_cfg.seed)
    env = spec.make_env(env_cfg, backend=backend, device=device, seed=agent_cfg.seed)
    try:
        resume_state = None
        if resume is not None:
            fw.load_policy(resume.path, env)  # a corrupt or mismatched checkpoint fails here
            resume_state = _resume_state(run, resume, env_cfg, console)
        wrappers.validate(_pipeline(fw, agent_cfg, video, None), fw.name)
        if video is not None:
            env.render()  # no GL, or an env that cannot render, fails before a run dir exists
        if stop.requested:
            raise _interrupted_before_run(stop)
        if run is None:
            run = runs.create(logs_dir, framework, task, run_name)
            runs.write_atomic(run.dir / runs.ENV_PARAMS, config.to_yaml(env_cfg))
        runs.write_atomic(run.dir / runs.AGENT_PARAMS, config.to_yaml(agent_cfg))
        argv = list(command) if command is not None else ["lab", *sys.argv[1:]]
        runs.write_atomic(run.dir / runs.COMMAND, shlex.join(argv) + "\n")
        manifest = {
            "task": task, "framework": framework, "seed": agent_cfg.seed, "device": device,
            "backend": env.backend, "num_envs": env.num_envs,
            "started": datetime.now().isoformat(timespec="seconds"), **runs.process_identity(),
            "state": runs.RUNNING, "versions": _versions(plugins.registry().provider(
                "framework", framework)),
        }
        if resume is not None:
            manifest["resumed_from"] = resume.path.name
        runs.write_json(run.dir / runs.MANIFEST, manifest)
        if resume_state is not None and resume_state["env"] is not None:
            env.resume_from(resume_state["env"])
        pipeline = _pipeline(fw, agent_cfg, video, run.dir)
        return _run_training(fw, env, agent_cfg, run, resume, resume_state, stop, device,
                             pipeline, console)
    finally:
        env.close()


def _pipeline(fw: Framework, cfg: AgentConfig, video: VideoSettings | None,
              run_dir: Path | None) -> list[wrappers.Step]:
    """The env-stage wrappers lab adds, then the framework's adapter and wrappers. The video
    folder is known once the run dir exists; the order is checked before either."""
    env_stage = [video.step(videos.folder(run_dir or Path(), videos.TRAIN))] if video else []
    return [*env_stage, *fw.pipeline(cfg)]


def _run_training(fw: Framework, env: LabVecEnv, cfg: AgentConfig, run: runs.Run,
                  resume: Checkpoint | None, resume_state: dict[str, Any] | None,
                  stop: interrupt.StopRequest, device: str, pipeline: list[wrappers.Step],
                  console: Console) -> TrainOutcome:
    description = f"{fw.name} · {env.task_spec.name} · {env.num_envs} envs"
    writer = SummaryWriter(log_dir=str(run.dir))
    progress = TrainProgress(cfg.max_iterations, description, console,
                             start=resume.iteration if resume else 0)
    ctx = TrainContext(cfg=cfg, env=env, framework=fw, run_dir=run.dir, seed=cfg.seed,
                       device=device, progress=progress, writer=writer, resume=resume,
                       resume_state=resume_state, stop=stop)
    t0 = time.perf_counter()
    # A runs table shows the run as running from now on; the real summary replaces this one.
    runs.write_json(run.dir / runs.SUMMARY, _summary(ctx, fw, run, runs.RUNNING, 0.0))
    state, error, wrapped = runs.FAILED, None, None
    try:
        wrapped = wrappers.apply(env, pipeline, fw.name)
        with progress, mjwarnings.counted(ctx.mujoco_warnings):
            fw.train(wrapped, ctx)
        state = runs.INTERRUPTED if stop.requested else runs.FINISHED
    except KeyboardInterrupt:  # a second signal: the stop itself was taking too long
        stop.request()
        state = runs.INTERRUPTED
    except TrainingDiverged as exc:
        error = exc
    except Exception as exc:
        # A library fails on NaN weights mid-update (e.g. sampling with a NaN std); any other
        # failure is a bug and keeps its traceback.
        if ctx.networks_finite():
            raise
        error = ctx.failed_on_networks(exc)
    finally:
        writer.close()
        ctx.last_good.discard()
        summary = _summary(ctx, fw, run, state, time.perf_counter() - t0)
        if error is not None:
            summary["error"] = error.message
        runs.write_json(run.dir / runs.SUMMARY, summary)
        run.update_manifest(state=state)
        if wrapped is not None:
            wrapped.close()  # env-stage wrappers write what they hold (a video cut short)
    if error is not None:
        raise error
    if state == runs.INTERRUPTED:
        summary["signal"] = stop.signum
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
        "mean_return": _finite_or_none(stats.get(metrics.MEAN_RETURN)),
        "mean_episode_length": _finite_or_none(stats.get(metrics.MEAN_LENGTH)),
        "success_rate": _finite_or_none(stats.get(metrics.SUCCESS_RATE)),
        "checkpoint": found[-1].path.name if found else None,
        "finished": datetime.now().isoformat(timespec="seconds"),
    }


def _finite_or_none(value: float | None) -> float | None:
    """JSON has no NaN: an undefined figure is null."""
    return value if value is not None and math.isfinite(value) else None
