"""`lab bench` as a library call: env-steps/s of any registered task, and training steps/s."""

from __future__ import annotations

import contextlib
import functools
import io
import itertools
import platform
import re
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import mujoco
import numpy as np
import torch
from mujoco import rollout
from rich.console import Console

from labcli.envs import metrics
from labcli.envs.env import LabVecEnv
from labcli.envs.make import make_env
from labcli.envs.shards import ShardedVecEnv
from labcli.errors import LabError
from labcli.plugins import registry
from labcli.plugins.policy import one_torch_thread
from labcli.runs import config, training
from labcli.runs.session import check_device

TRAIN_ITERATIONS = 5
# The cpu backend and its rollout reference take turns in this many windows (`beside_rollout`).
WINDOWS = 4


@dataclass
class BenchRow:
    task: str
    backend: str
    num_envs: int
    env_steps_per_s: float
    framework: str | None = None
    train_steps_per_s: float | None = None
    threads: int | None = None  # the cpu backend's physics threads
    # raw physics of the same model and decimation in the same run: `mujoco.rollout` (cpu
    # backend) or MuJoCo Warp's step (warp)
    rollout_steps_per_s: float | None = None
    ratio_to_rollout: float | None = None

    def as_dict(self) -> dict:
        return asdict(self)


def rate(step: Callable[[], int], seconds: float, sync: Callable[[], None] = lambda: None) -> float:
    """Env-steps/s of `step` (which returns the env-steps it took), after a warm-up. `sync`
    waits for queued device work, so that a GPU is timed on what it did, not what it was given."""
    for _ in range(3):
        step()
    sync()
    count, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        count += step()
    sync()
    return count / (time.perf_counter() - start)


def env_stepper(env: LabVecEnv | ShardedVecEnv, banked: int = 16) -> Callable[[], int]:
    """One step of the env as a learner sees it, from a reset: uniform random actions in
    (`banked` sets drawn beforehand, in turn, as the rollout's controls are: drawing them is the
    learner's work, not the env's), torch tensors out."""
    env.reset(seed=0)
    gen = torch.Generator(env.device).manual_seed(0)
    shape = (env.num_envs, env.single_action_space.shape[0])
    turn = itertools.cycle([torch.rand(shape, generator=gen, device=env.device) * 2 - 1
                            for _ in range(banked)])

    def step() -> int:
        env.step(next(turn))
        return env.num_envs

    return step


def env_rate(env: LabVecEnv | ShardedVecEnv, seconds: float, banked: int = 16) -> float:
    """Env-steps/s of `env_stepper`, on the CPU on one torch thread, as lab's learners run it
    (`one_torch_thread`). Measured on 16 cores at 4,096 cartpole envs: 293k env-steps/s with
    torch's 16 threads, 699k with one."""
    sync = torch.cuda.synchronize if env.device.type == "cuda" else (lambda: None)
    with one_torch_thread(str(env.device)):
        return rate(env_stepper(env, banked), seconds, sync)


def physics_rate(env: LabVecEnv, seconds: float) -> float:
    """The limit of the warp backend: env-steps/s of MuJoCo Warp's own step of what `env`
    steps (its model and batched data, `decimation` physics steps per env step, replayed as the
    env replays it, as a CUDA graph), from the env's current states with its last controls held,
    no task code."""
    sim = env.unwrapped.sim
    n, nstep = sim.num_envs, env.unwrapped.cfg.decimation

    def step() -> int:
        sim.step(nstep)
        return n

    return rate(step, seconds, torch.cuda.synchronize)


@contextlib.contextmanager
def rollout_steppers(env: LabVecEnv, banked: int = 16) -> Iterator[list[Callable[[], int]]]:
    """The limit of the cpu backend: steps of bare `mujoco.rollout` of what `env` steps, without
    it: the env's own models (sensors included; one per env where the task varies the physics
    per env), from the env's current states, `decimation` physics steps per env step with the
    controls the task's actuation makes of uniform random actions (`banked` sets drawn
    beforehand, in turn), on the env's threads (MuJoCo's pool, as the cpu backend on more than
    two); the state copied out, no task code, no resets but of diverged envs.

    One stepper per chunking, whose faster one is the reference: one chunk of envs per thread,
    and MuJoCo's default (ten per thread), which balances unequal cores (a 16-core host:
    0.99–1.15 of one per thread; a 2-core VM: 0.85)."""
    sim, n, nstep = env.sim, env.num_envs, env.cfg.decimation
    model, nthread = sim.model, sim.nthread
    gen = torch.Generator().manual_seed(0)
    controls = []
    for _ in range(banked):
        env.task.apply_actions(torch.rand(n, len(env.action_names), generator=gen) * 2 - 1)
        controls.append(sim.ctrl.numpy()[:, None, :].repeat(nstep, axis=1))
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    datas = [mujoco.MjData(model) for _ in range(max(nthread, 1))]
    initial = np.empty(mujoco.mj_stateSize(model, full))
    mujoco.mj_getState(model, datas[0], initial, full)
    state = sim.physics_state()
    runner = rollout.Rollout(nthread=nthread if nthread > 1 else 0)
    states = np.empty((n, nstep, state.shape[1]))
    sensors = np.empty((n, nstep, model.nsensordata))  # recorded, as the backend does
    turn = itertools.cycle(controls)

    def step(chunk_size: int | None) -> int:
        runner.rollout(sim.models, datas, state, next(turn), nstep=nstep, skip_checks=True,
                       state=states, sensordata=sensors, chunk_size=chunk_size)
        state[:] = states[:, -1]
        state[~np.isfinite(state).all(axis=1)] = initial
        return n

    # One chunk a thread; on more threads than one also MuJoCo's default chunking (None).
    chunk_sizes = (-(-n // len(datas)), *((None,) if len(datas) > 1 else ()))
    try:
        yield [functools.partial(step, chunk_size) for chunk_size in chunk_sizes]
    finally:
        runner.close()


def beside_rollout(env: LabVecEnv | ShardedVecEnv, reference: LabVecEnv, seconds: float,
                   windows: int = WINDOWS) -> tuple[float, float]:
    """Env-steps/s of the cpu backend's `env` and of the rollout of what it steps (`reference`,
    which takes the states `env` reached in its first window: a robot's contacts cost more than
    its first pose), each a median over `windows` windows in turn of `seconds / windows`. Timed
    in turn, not one after the other: on a shared 16-core host a core's speed moved within
    seconds (one shard's torch code took 235 µs a step in one run and 485 µs in the next), and
    the ratio of two runs apart measured that drift as much as lab."""
    window = seconds / windows
    with one_torch_thread("cpu"):
        step = env_stepper(env)
        lab = [rate(step, window)]
        reference.set_state(env.get_state())
        with rollout_steppers(reference) as steppers:
            pool: list[list[float]] = [[] for _ in steppers]
            for turn in range(windows):
                if turn:
                    lab.append(rate(step, window))
                for rates, pooled in zip(pool, steppers, strict=True):
                    rates.append(rate(pooled, window))
    return statistics.median(lab), max(statistics.median(rates) for rates in pool)


def train_rate(task: str, framework: str, num_envs: int, backend: str | None,
               device: str, overrides: Sequence[str] = ()) -> float:
    """Steps/s of a short training run (collection and updates) in a throwaway logs dir."""
    with tempfile.TemporaryDirectory(prefix="lab_bench_") as logs:
        outcome = training.train(task, framework, num_envs=num_envs, device=device,
                                 backend=backend, max_iterations=TRAIN_ITERATIONS,
                                 overrides=overrides,
                                 logs_dir=Path(logs), console=Console(file=io.StringIO()),
                                 command=["lab", "bench"])
    return outcome.summary["steps"] / max(outcome.summary["wall_time_s"], 1e-9)


def time_to_success(run_dir: Path, threshold: float) -> tuple[float, int] | None:
    """Seconds of training (event wall time since the run's first event, which is written once
    the env is built) and steps at which the logged success rate first reached `threshold`."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(run_dir), size_guidance={"scalars": 0})
    events.Reload()
    if metrics.SUCCESS_RATE not in events.Tags()["scalars"]:
        return None
    start = events.FirstEventTimestamp()
    for scalar in events.Scalars(metrics.SUCCESS_RATE):
        if scalar.value >= threshold:
            return scalar.wall_time - start, scalar.step
    return None


def cpu_name() -> str:
    """The CPU's model name as Linux reports it (`platform.processor()` is empty there), else
    what `platform` knows."""
    cpuinfo = Path("/proc/cpuinfo")
    names = (re.findall(r"^model name\s*:\s*(.+)$", cpuinfo.read_text(), re.M)
             if cpuinfo.exists() else [])
    return names[0] if names else platform.processor() or platform.machine()


def _played_success(checkpoint: Path, episodes: int, seed: int) -> float:
    from labcli.runs import play

    return play.play(checkpoint=checkpoint, episodes=episodes, seed=seed)[1].success_rate


def played_to_success(run_dir: Path, threshold: float, episodes: int = 64,
                      seed: int = 1, workers: int = 1) -> dict:
    """The run's complete checkpoints played in order, as `lab play --checkpoint` plays them
    (on the CPU, without their exploration noise, `episodes` episodes from `seed`), up to the
    first that ended at least `threshold` of them successfully. `reached`: that one's
    iteration, success rate, and the seconds of training (its manifest's time since the run's
    first event) and env steps (the last logged before it) at which it was saved, None if none
    did; `rates`: [iteration, success rate] of each checkpoint played, so that a run which never
    got there shows how near it came. Training's own success rate counts episodes played under
    the noise, which can hide a policy that has learnt. `workers` > 1 plays that many
    checkpoints at once, each in its own process (a play runs on one core)."""
    import concurrent.futures
    import multiprocessing

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from labcli.runs import checkpoints, rundir

    run = rundir.open_run(run_dir)
    fw = registry.get_framework(run.identity()[1])
    events = EventAccumulator(str(run_dir), size_guidance={"scalars": 0})
    events.Reload()
    start = events.FirstEventTimestamp()
    logged = events.Scalars(metrics.STEPS_PER_S)
    found = [c for c in fw.checkpoints(run_dir) if checkpoints.complete(fw, c)]
    pool = (concurrent.futures.ProcessPoolExecutor(
        workers, mp_context=multiprocessing.get_context("spawn")) if workers > 1 else None)
    play_all = pool.map if pool else map
    judge = functools.partial(_played_success, episodes=episodes, seed=seed)
    rates = []
    try:
        # In order, up to `workers` at once; those not begun when one succeeds are cancelled.
        for checkpoint, rate in zip(found, play_all(judge, [c.path for c in found]), strict=True):
            rates.append([checkpoint.iteration, rate])
            if rate >= threshold:
                saved = checkpoints.manifest_path(run_dir, checkpoint.iteration).stat().st_mtime
                steps = max((e.step for e in logged if e.wall_time <= saved), default=0)
                return {"reached": {"iteration": checkpoint.iteration, "success": rate,
                                    "seconds": saved - start, "steps": steps},
                        "rates": rates}
    finally:
        if pool:
            pool.shutdown(cancel_futures=True)
    return {"reached": None, "rates": rates}


def bench(task: str, num_envs: Sequence[int], *, backend: str | None = None,
          device: str | None = None, framework: str | None = None,
          seconds: float = 3.0, threads: Sequence[int] = (),
          overrides: Sequence[str] = ()) -> list[BenchRow]:
    """A row per thread count (cpu backend; none given: the cores this process may use) and env
    count, in that order: each env measured beside the rollout of what it steps on as many
    threads (in turns, `beside_rollout`), so that the ratio says how much of the cores' physics
    lab keeps. `overrides`: `--set` settings of the env (and of the training run)."""
    spec = registry.get_task(task)
    if framework is not None:
        registry.get_framework(framework)  # an unknown name fails before any measuring
    device = check_device(device, backend)
    if not num_envs or any(n <= 0 for n in num_envs):
        raise LabError(f"--num-envs must be positive integers, got {list(num_envs)}",
                       "e.g. --num-envs 16,256,1024")
    if any(t <= 0 for t in threads):
        raise LabError(f"--threads must be positive integers, got {list(threads)}",
                       "e.g. --threads 2,4,8,16, or leave it out to use the cores this process "
                       "may use")
    if not 0 < seconds <= 3600:
        raise LabError(f"--seconds must be more than 0 and at most 3600, got {seconds:g}")
    settings = [[*overrides, f"env.threads={t}"] for t in threads] or [list(overrides)]
    # Validated as `lab train` validates them: a count past the config's bounds is one line.
    runs = [(overrides, config.build(spec.config_class, "env", [config.parse_set(
        [f"env.num_envs={n}", *overrides])["env"]])) for overrides in settings for n in num_envs]
    rows = []
    for overrides, cfg in runs:
        env = make_env(spec, cfg, backend=backend, device=device)
        try:
            if env.backend == "cpu":
                # On MuJoCo's pool of the env's threads, whether the env steps in shards or not.
                reference = LabVecEnv(spec, cfg, backend="cpu")
                try:
                    lab, pool = beside_rollout(env, reference, seconds)
                    row = BenchRow(task, "cpu", cfg.num_envs, lab, threads=reference.sim.nthread,
                                   rollout_steps_per_s=pool, ratio_to_rollout=lab / pool)
                finally:
                    reference.close()
            else:
                lab = env_rate(env, seconds)
                raw = physics_rate(env, seconds)
                row = BenchRow(task, env.backend, cfg.num_envs, lab,
                               rollout_steps_per_s=raw, ratio_to_rollout=lab / raw)
        finally:
            env.close()
        if framework is not None:
            row.framework = framework
            row.train_steps_per_s = train_rate(task, framework, cfg.num_envs, backend, device,
                                               overrides)
        rows.append(row)
    return rows
