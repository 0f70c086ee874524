"""One training session of a run: build the env and the pipeline, write the run dir's files, let
the framework train with lab's TrainContext, and write the summary however it ends. Imports torch
and the framework's library; `labcli/runs/training.py` has planned and announced it first."""

from __future__ import annotations

import contextlib
import errno
import math
import os
import shlex
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import torch
from rich.console import Console
from torch.utils.tensorboard import SummaryWriter

from labcli import __version__, files
from labcli.envs import metrics, mjwarnings, models, wrappers
from labcli.envs.config import TaskConfig
from labcli.envs.cores import available_memory, cores, gib
from labcli.envs.make import make_env
from labcli.envs.sim import WARP_INSTALL_HINT, default_backend
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.plugins.config import AgentConfig
from labcli.plugins.framework import Checkpoint, Framework, StopTraining
from labcli.runs import (
    checkpoints,
    config,
    distributed,
    interrupt,
    loading,
    loggers,
    precision,
    rundir,
    snapshot,
)
from labcli.runs import video as videos
from labcli.runs.context import IterationHook, RunContext, StopAtRequest
from labcli.runs.plan import TrainPlan
from labcli.runs.progress import TrainProgress
from labcli.runs.ranks import SINGLE, Ranks
from labcli.runs.video import VideoSettings


@dataclass
class TrainOutcome:
    run: rundir.Run
    summary: dict[str, Any]
    # How far the checkpoints' Policies acted from the live agent at most (see
    # TrainContext.set_actor); None when the framework gave no actor.
    policy_difference: float | None = None
    ranks: Ranks = SINGLE


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


def run(plan: TrainPlan, stop: interrupt.StopRequest, console: Console,
        command: list[str] | None = None, on_iteration: IterationHook | None = None,
        ranks: Ranks = SINGLE) -> TrainOutcome:
    """Build what `plan` says and train; nothing is written before the env and the checkpoint
    to resume from are known to work, and a resumed run is held against a second writer. In a
    data-parallel run (`ranks`) this is one rank's share, and only rank 0 writes."""
    device = distributed.device_of(ranks, check_device(plan.device, plan.backend))
    # Before the library is imported: RSL-RL and skrl join a process group that exists.
    with distributed.process_group(ranks, device), precision.tf32(plan.agent_cfg.tf32):
        session = _Session(plan, stop, console, command, on_iteration, ranks, device)
        try:
            if plan.run is None or not ranks.writer:
                return session.run()
            with rundir.writing(plan.run):
                return session.run()
        except RuntimeError as exc:  # rank 0 failed before training (and said why)
            if ranks.active and distributed.lost_peer(exc):
                raise distributed.lost(ranks, exc) from None
            raise


@dataclass
class _Session:
    plan: TrainPlan
    stop: interrupt.StopRequest
    console: Console
    command: list[str] | None
    on_iteration: IterationHook | None
    ranks: Ranks
    device: str

    def run(self) -> TrainOutcome:
        plan, ranks = self.plan, self.ranks
        fw = plan.framework.load()
        env_cfg, agent_cfg, run_ = plan.env_cfg, plan.agent_cfg, plan.run
        if ranks.writer:
            # Before any simulation: a run that cannot be written must not cost a minute of
            # start-up.
            rundir.check_writable(plan.write_dir)
        before = _previous(run_)

        seed = agent_cfg.seed + ranks.rank  # each rank its own episodes and exploration
        if ranks.local_world_size > 1 and env_cfg.threads is None:
            # The host's cores shared out: each rank's physics on as many threads as all of
            # them would oversubscribe the cores by the number of ranks.
            share = max(1, cores() // ranks.local_world_size)
            env_cfg = env_cfg.model_copy(update={"threads": share})
        snapshot.seed_all(seed)
        env = make_env(plan.spec, env_cfg, backend=plan.backend, device=self.device, seed=seed)
        try:
            if env.critic_observation_size and not fw.spec.critic_observations:
                self.console.print(f"note: {fw.name} has no critic input of its own: its critic "
                                   "reads the policy's observations, noise included "
                                   "(env.critic_observations is for rsl_rl and skrl)",
                                   highlight=False)
            _check_memory(agent_cfg, env, self.device)
            agent_cfg.check_env(env)
            resume_state = None
            if plan.resume is not None:
                # A corrupt, mismatched or NaN checkpoint fails here, before anything is written.
                loading.policy_of(fw, plan.resume, env, agent_cfg)
                resume_state = _resume_state(run_, plan.resume, env, env_cfg, self.console,
                                             ranks)
                for what in checkpoints.missing_companions(fw.spec, plan.resume):
                    self.console.print(f"note: {plan.resume.path.name} holds no {what} (only "
                                       "a run's newest checkpoint keeps it); the resumed run "
                                       "starts with an empty one", highlight=False)
            wrappers.validate(_pipeline(fw, agent_cfg, self.video, None), fw.name)
            if self.video is not None:
                env.render()  # no GL, or an env that cannot render, fails before a run dir
            if self.stop.requested and not ranks.active:
                raise interrupt.before_run(self.stop)
            if run_ is None and ranks.writer:
                run_ = rundir.create(plan.logs_dir, fw.name, plan.spec.name, plan.run_name)
                if ranks.active:
                    distributed.broadcast_from_writer(str(run_.dir))
                with rundir.writing(run_):
                    return self._start(fw, env, run_, resume_state, before)
            if run_ is None:  # the run dir rank 0 made: the others only read what it holds
                run_ = rundir.Run(Path(distributed.broadcast_from_writer(None)))
            return self._start(fw, env, run_, resume_state, before)
        finally:
            env.close()

    @property
    def video(self) -> VideoSettings | None:
        return self.plan.video if self.ranks.writer else None

    def _start(self, fw: Framework, env: Any, run_: rundir.Run,
               resume_state: dict[str, Any] | None, before: dict[str, Any]) -> TrainOutcome:
        """Write the run dir's files (the params this session trains with, its command, the
        manifest with every session so far), then train."""
        plan = self.plan
        if self.ranks.writer:
            self._write_session(fw, env, run_, before)
        if resume_state is not None and resume_state["env"] is not None:
            env.resume_from(resume_state["env"])
        elif getattr(env.cfg, "stagger_episodes", False):  # a gymnasium task has no such setting
            env.start_staggered()
        if self.video is not None:  # no link planted on the way: videos go into the run dir
            files.real_dir(videos.folder(run_.dir, videos.TRAIN), below=run_.dir)
        pipeline = _pipeline(fw, plan.agent_cfg, self.video, run_.dir)
        earlier = before["summary"]
        earlier_wall = earlier.get("total_wall_time_s", earlier.get("wall_time_s", 0.0))
        changed = frozenset(key.removeprefix("agent.") for key in plan.changes
                            if key.startswith("agent."))
        return _run_training(fw, env, plan.agent_cfg, run_, plan.resume, resume_state,
                             self.stop, self.device, pipeline, self.console, earlier_wall,
                             changed, self.on_iteration, self.ranks, self._wandb_config())

    def _wandb_config(self) -> dict[str, Any] | None:
        """The settings a W&B run records (`--logger wandb`); None: no W&B."""
        plan = self.plan
        if plan.logger != "wandb":
            return None
        return {"task": plan.spec.name, "framework": plan.framework.name,
                "env": plan.env_cfg.model_dump(mode="json"),
                "agent": plan.agent_cfg.model_dump(mode="json")}

    def _write_session(self, fw: Framework, env: Any, run_: rundir.Run,
                       before: dict[str, Any]) -> None:
        plan, agent_cfg = self.plan, self.plan.agent_cfg
        rundir.write_atomic(run_.dir, rundir.ENV_PARAMS, config.to_yaml(plan.env_cfg))
        rundir.write_atomic(run_.dir, rundir.AGENT_PARAMS, config.to_yaml(agent_cfg))
        argv = list(self.command) if self.command is not None else ["lab", *sys.argv[1:]]
        rundir.write_atomic(run_.dir, rundir.COMMAND, shlex.join(argv) + "\n")
        now = datetime.now().isoformat(timespec="seconds")
        old = before["manifest"]
        session = {"started": now, "command": shlex.join(argv)}
        if plan.resume is not None:
            session["resumed_from"] = plan.resume.path.name
            session["changed"] = {key: [old_value, new] for key, (old_value, new)
                                  in plan.changes.items()}
        manifest = {
            "task": plan.spec.name, "framework": fw.name, "seed": agent_cfg.seed,
            "device": self.device, "backend": env.backend, "num_envs": env.num_envs,
            "started": now, "first_started": old.get("first_started", old.get("started", now)),
            **rundir.process_identity(), "state": rundir.RUNNING,
            "versions": _versions(fw.spec.library,
                                  registry.loaded().provider(registry.FRAMEWORK, fw.name)),
            "sessions": [*old.get("sessions", []), session],
        }
        if self.ranks.active:  # num_envs is each rank's
            manifest["ranks"] = self.ranks.world_size
        if hasattr(plan.spec, "model"):  # lab's own tasks: the model play and resume rebuild
            manifest["model"] = models.describe(plan.spec.model)
        if plan.resume is not None:
            manifest["resumed_from"] = plan.resume.path.name
        rundir.write_json(run_.dir, rundir.MANIFEST, manifest)


def _check_memory(cfg: AgentConfig, env: Any, device: str) -> None:
    """Refuse settings whose buffers and networks cannot fit in the memory left on the
    learner's device, naming the setting that asks for most: torch or NumPy would fail deep
    inside the library, or the OS would kill the process."""
    needs = cfg.memory(env.num_envs, env.single_observation_space.shape[0],
                       env.single_action_space.shape[0])
    free = _free_memory(device)
    total = sum(needs.values())
    if free is None or total <= free:
        return
    key, largest = max(needs.items(), key=lambda item: item[1])
    value = getattr(cfg, key.removeprefix("agent."), None)
    in_all = f" ({gib(total)} for the learner in all)" if total > largest * 1.01 else ""
    raise LabError(f"{key}={value!r} with {env.num_envs} envs needs {gib(largest)} of "
                   f"memory{in_all}, more than the {gib(free)} free on {device}",
                   f"lower {key}, or the env count")


def _free_memory(device: str) -> int | None:
    """Bytes free on `device`: CUDA's count, or Linux's MemAvailable; None where unknown."""
    if torch.device(device).type == "cuda":
        return torch.cuda.mem_get_info(torch.device(device))[0]
    return available_memory()


def _previous(run: rundir.Run | None) -> dict[str, Any]:
    """What a resumed run's earlier sessions recorded: its manifest and summary."""
    if run is None:
        return {"manifest": {}, "summary": {}}
    return {"manifest": run.manifest(), "summary": run.summary() or {}}


def _versions(library: str, fw_provider: registry.Provider) -> dict[str, str]:
    out = {"lab": __version__}
    for dist in ("mujoco", "torch", "gymnasium", library, fw_provider.dist):
        found = dist and registry.installed(dist)
        if found:
            out[dist] = found
    return out


def _resume_state(run: rundir.Run, resume: Checkpoint, env: Any, env_cfg: TaskConfig,
                  console: Console, ranks: Ranks) -> dict[str, Any] | None:
    """The env and generator state saved with `resume` (this rank's, in a data-parallel run),
    or None (with a note saying what that changes) when there is none or it cannot apply; a
    LabError when it is damaged."""
    path = snapshot.path_of(run.dir, resume.iteration)
    state = snapshot.load(path)
    if state is None:
        console.print(f"note: {resume.path.name} has no saved env and random-generator state; "
                      "the resumed run starts new episodes", highlight=False)
        return None
    others = state.get("ranks", [])
    if ranks.world_size != len(others) + 1:
        console.print(f"note: {resume.path.name} was saved by {len(others) + 1} rank(s), not "
                      f"{ranks.world_size}; ranks other than 0 start new episodes",
                      highlight=False)
        if ranks.rank > 0:
            return None
    elif ranks.rank > 0:
        state = {**state, **others[ranks.rank - 1]}
    saved = state["env"]
    if saved is None:
        console.print(f"note: the env of {resume.path.name} cannot save its episodes; the "
                      "resumed run starts new ones", highlight=False)
        return state
    qpos = saved.get("qpos")
    if isinstance(qpos, torch.Tensor) and qpos.ndim == 2 and qpos.shape[0] != env_cfg.num_envs:
        console.print(f"note: {resume.path.name} was saved with {qpos.shape[0]} envs, not "
                      f"{env_cfg.num_envs}; the resumed run starts new episodes", highlight=False)
        return None
    try:
        env.check_state(saved)
    except LabError as exc:
        raise LabError(f"resume state {path}: {exc.message}", exc.hint) from None
    return state


def _pipeline(fw: Framework, cfg: AgentConfig, video: VideoSettings | None,
              run_dir: Path | None) -> list[wrappers.Step]:
    """The env-stage wrappers lab adds, then the framework's adapter and wrappers. The video
    folder is known once the run dir exists; the order is checked before either."""
    env_stage = [video.step(videos.folder(run_dir or Path(), videos.TRAIN))] if video else []
    return [*env_stage, *fw.pipeline(cfg)]


def update_threads(env: Any, ranks: Ranks) -> int:
    """Half the cores this run's physics may use (its threads, or its rank's share of the
    host), two where there are two or three, and no more than OMP_NUM_THREADS where it is set.
    On 16 cores the update on 8 threads made RSL-RL's cartpole train at 2.1x (1,024 envs) and
    2.6x (4,096) the steps/s of one, its humanoid at 2.6x (1,024); on all 16 skrl's cartpole
    slowed to 0.68x. On 2 cores both made ant and humanoid train at 1.1-1.5x the steps/s of
    one; but two trainings sharing them then run four update threads that contend (each at half
    its speed), which OMP_NUM_THREADS=1 avoids."""
    physics = getattr(env, "threads", None) or max(1, cores() // ranks.local_world_size)
    return min(max(min(2, physics), physics // 2), _omp_threads() or physics)


def _omp_threads() -> int | None:
    """OMP_NUM_THREADS's count (its first level's), or None where it is unset or not one."""
    try:
        count = int(os.environ.get("OMP_NUM_THREADS", "").split(",")[0])
    except ValueError:
        return None
    return count if count > 0 else None


@contextlib.contextmanager
def _writer_thread_quiet() -> Iterator[None]:
    """TensorBoard writes from a thread of its own, which prints a traceback when its file's
    directory was deleted or the disk filled up; the same error reaches lab through the
    writer's next call, and lab says it in one line: the thread's own print is left out."""
    original = threading.excepthook

    def hook(args: threading.ExceptHookArgs) -> None:
        if not (type(args.thread).__name__ == "_AsyncWriterThread"
                and issubclass(args.exc_type, OSError)):
            original(args)

    threading.excepthook = hook
    try:
        yield
    finally:
        threading.excepthook = original


@_writer_thread_quiet()
def _run_training(fw: Framework, env: Any, cfg: AgentConfig, run: rundir.Run,
                  resume: Checkpoint | None, resume_state: dict[str, Any] | None,
                  stop: interrupt.StopRequest, device: str, pipeline: list[wrappers.Step],
                  console: Console, earlier_wall: float, changed: frozenset[str],
                  on_iteration: IterationHook | None, ranks: Ranks,
                  wandb_config: dict[str, Any] | None) -> TrainOutcome:
    envs = (f"{ranks.world_size} ranks × {env.num_envs} envs" if ranks.active
            else f"{env.num_envs} envs")
    description = f"{fw.name} · {env.task_spec.name} · {envs}"
    writer = (loggers.Figures(SummaryWriter(log_dir=str(run.dir))) if ranks.writer
              else _NoWriter())
    progress = TrainProgress(cfg.max_iterations, description, console,
                             start=resume.iteration if resume else 0)
    ctx = RunContext(cfg=cfg, env=env, framework=fw, run_dir=run.dir, seed=cfg.seed,
                     device=device, progress=progress, writer=writer, resume=resume,
                     resume_state=resume_state, stop=stop, changed=changed,
                     on_iteration=on_iteration, ranks=ranks,
                     update_threads=update_threads(env, ranks))
    t0 = time.perf_counter()

    def summary_of(state: str) -> dict[str, Any]:
        return _summary(ctx, fw, run, state, time.perf_counter() - t0, earlier_wall)

    if ranks.writer:
        # A runs table shows the run as running from now on; the real summary replaces this.
        rundir.write_json(run.dir, rundir.SUMMARY, summary_of(rundir.RUNNING))
    state, error, wrapped = rundir.FAILED, None, None
    # A data-parallel rank never leaves mid-rollout: the others would wait for it in the next
    # update. Its stop is agreed on at the end of the iteration (RunContext.end_iteration).
    stop_mid_rollout = stop if not ranks.active else interrupt.StopRequest()
    try:
        if wandb_config is not None and ranks.writer:
            writer.join_wandb(run.dir, wandb_config)
        wrapped = wrappers.apply(StopAtRequest(env, stop_mid_rollout), pipeline, fw.name)
        # StopTraining out of a plugin that leaves ctx.training out: its saves stand.
        with progress, mjwarnings.counted(ctx.mujoco_warnings), \
                contextlib.suppress(StopTraining):
            fw.train(wrapped, ctx)
        state = rundir.INTERRUPTED if stop.requested else rundir.FINISHED
    except LabError as exc:  # diverged (exit 3), or the run dir cannot be written any more
        error = exc
    except Exception as exc:
        # A library's own writer finds the run dir deleted under lab, or a library fails on NaN
        # weights mid-update (e.g. sampling with a NaN std); any other failure is a bug and
        # keeps its traceback.
        if (deleted := files.deletion(exc, run.dir)) is not None:
            error = deleted
        elif isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            # TensorBoard's writer or a library's own, on a full disk: its checkpoints stand.
            error = files.unwritable(run.dir, exc)
        elif ranks.active and distributed.lost_peer(exc):
            error = distributed.lost(ranks, exc, ctx.iteration)
        elif ctx.networks_finite():
            raise
        else:
            error = ctx.failed_on_networks(exc)
    finally:
        _close(writer, console)
        if ranks.writer and (physics := ctx.physics_summary()) is not None:
            console.print(physics, highlight=False, soft_wrap=True)
        summary = summary_of(state)
        if error is not None:
            summary["error"] = error.message
        if ranks.writer:
            ctx.last_good.discard()
            _write_end(run, summary, state, console)
        if wrapped is not None:
            wrapped.close()  # env-stage wrappers write what they hold (a video cut short)
    if error is not None:
        raise error
    if state == rundir.INTERRUPTED:
        summary["signal"] = stop.signum
    return TrainOutcome(run, summary, ctx.policy_difference, ranks)


class _NoWriter:
    """TensorBoard's writer on a rank other than 0, which writes nothing: any of
    SummaryWriter's calls (a library's own figures) is accepted and dropped."""

    def __getattr__(self, name: str) -> Any:
        return lambda *args, **kwargs: None


def _close(writer: loggers.Figures | _NoWriter, console: Console) -> None:
    try:
        writer.close()
    except OSError as exc:  # a full disk: TensorBoard could not write its last figures
        console.print(f"note: TensorBoard's last figures were not written: {exc.strerror}",
                      highlight=False)


def _write_end(run: rundir.Run, summary: dict[str, Any], state: str, console: Console) -> None:
    """The summary and the manifest's state, where they can still be written (a full disk, a
    deleted run dir: said in one line, which the run's error follows)."""
    try:
        rundir.write_json(run.dir, rundir.SUMMARY, summary)
        run.update_manifest(state=state)
    except LabError as exc:
        console.print(f"note: the run's summary was not written: {exc.message}",
                      highlight=False, soft_wrap=True)


def _summary(ctx: RunContext, fw: Framework, run: rundir.Run, state: str,
             wall: float, earlier_wall: float) -> dict[str, Any]:
    found = checkpoints.latest_complete(fw.spec, run.dir)
    stats = ctx.last_stats
    # An interrupted run goes on from its checkpoint: the summary claims no more than that.
    iterations, steps = ((ctx.saved_iteration, ctx.saved_steps) if state == rundir.INTERRUPTED
                         and ctx.saved_iteration >= 0 else (ctx.iteration, ctx.steps))
    return {
        "state": state,
        "iterations": iterations,
        "steps": steps,
        "wall_time_s": round(wall, 2),
        "total_wall_time_s": round(earlier_wall + wall, 2),
        "mean_return": _finite_or_none(stats.get(metrics.MEAN_RETURN)),
        "mean_episode_length": _finite_or_none(stats.get(metrics.MEAN_LENGTH)),
        "success_rate": _finite_or_none(stats.get(metrics.SUCCESS_RATE)),
        "terrain_level": _finite_or_none(stats.get(metrics.TERRAIN_LEVEL)),
        "checkpoint": found.path.name if found else None,
        "finished": datetime.now().isoformat(timespec="seconds"),
    }


def _finite_or_none(value: float | None) -> float | None:
    """JSON has no NaN: an undefined figure is null."""
    return value if value is not None and math.isfinite(value) else None
