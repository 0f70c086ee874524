"""The cpu backend on two or more threads: the envs in shards, one process each.

Each shard is a whole `LabVecEnv` of its envs that steps its physics on one thread (MuJoCo's
rollout on its own calling thread) and runs its task's torch code on its own core: the torch
code's per-op cost, which does not shrink with more envs, is paid by every shard at once
instead of once in series after MuJoCo's pool (on a 16-core host, 0.80–1.18 of the pool's
rollout against 0.59–0.82 for one process; docs/benchmarks.md). The calling process steps
shard 0 itself; the others are worker processes that read the actions from and write their
outputs to shared memory, in lockstep with it. Envs draw per block (`labcli.envs.random`), so a
fixed seed gives the same outputs whatever the number of shards.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import time
import traceback
import weakref
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
import torch.multiprocessing as mp
from gymnasium.vector import AutoresetMode

from labcli.envs.compiled import compiling_notice
from labcli.envs.config import TaskConfig
from labcli.envs.cores import cores
from labcli.envs.env import (
    LabVecEnv,
    Reduce,
    StepOutputs,
    _autoreset_mode,
    checked_actions,
    closed_error,
    reset_mask,
)
from labcli.envs.random import BLOCKS, EnvRandom, block_bounds
from labcli.envs.sharedmem import shared
from labcli.envs.sim.chunks import ChunkBoard, ShardPhysics
from labcli.envs.sim.cpu import check_fits
from labcli.envs.spec import TaskSpec
from labcli.errors import LabError, first_line

# Fewer envs than this in a shard, and its process costs more than it saves (prototype: 64
# cartpole envs a shard on 16 cores still gained; shards of 16 lost).
MIN_SHARD_ENVS = 64
# How long a waiting process polls before it sleeps: a step's gap is shorter than a sleep's
# wake-up on a VM, a learner's update (the workers' wait) longer.
SPIN_S = 0.002
# A worker's flags in shared memory, read on every step instead of polling its pipe (a system
# call each, ~3 µs on a VM, 15 of them in series in the caller on 16 cores): the caller has sent
# a command; the worker's step failed (its error is in the pipe).
COMMAND, FAILED = 0, 1
# How often a waiting worker checks that its parent lives: a worker ends within this long of
# the caller's death.
ORPHAN_CHECK_S = 0.5
# How long a step waits for its workers once the run was asked to stop.
STOP_GRACE_S = 10.0


def shard_count(num_envs: int, threads: int | None) -> int:
    """How many processes step `num_envs` envs on `threads` threads: one per thread up to the
    env's blocks and the cores this process may use (a process waiting its turn for a core
    stalls them all), in a power of two so that every shard holds as many blocks. On two
    threads too: on a 2-core VM two shards stepped cartpole at 1.05-1.17x the env-steps/s of one
    process with two physics threads (128 to 4,096 envs), ant, humanoid and go1-flat at
    1.05-1.09x (1,024), as one process runs all its torch code on one of its cores."""
    threads = min(threads or cores(), cores())
    count = 1
    while count * 2 <= min(threads, BLOCKS, num_envs // MIN_SHARD_ENVS):
        count *= 2
    return count


@dataclass
class _Shard:
    first: int
    stop: int
    blocks: slice


def _layout(num_envs: int, count: int) -> list[_Shard]:
    bounds = block_bounds(num_envs)
    per, left = divmod(len(bounds) - 1, count)
    if left or not per:
        raise LabError(f"{num_envs} envs are {len(bounds) - 1} blocks: they do not make "
                       f"{count} shards of whole blocks", "ask for a power of two up to "
                       f"{len(bounds) - 1} shards")
    return [_Shard(bounds[i * per], bounds[(i + 1) * per], slice(i * per, (i + 1) * per))
            for i in range(count)]


def _buffers(env: LabVecEnv, num_envs: int, count: int) -> dict[str, torch.Tensor]:
    """The tensors the processes share: the actions in, every output of a step out."""
    outputs = env.new_outputs(num_envs, shared)
    return {f.name: getattr(outputs, f.name) for f in fields(StepOutputs)
            if getattr(outputs, f.name) is not None} | {
        name: shared(tensor) for name, tensor in {
            "actions": torch.zeros(num_envs, env.single_action_space.shape[0]),
            "stats": torch.zeros(count, env.stats_size, dtype=torch.float64),
            "flags": torch.zeros(count, 2, dtype=torch.uint8)}.items()}


def _serve(spec: TaskSpec, cfg: TaskConfig, seed: int, mode: AutoresetMode, shard: _Shard,
           total: int, index: int, buffers: dict[str, torch.Tensor], board: ChunkBoard,
           go: Any, done: Any, conn: Any) -> None:
    """A worker process: build its shard, then serve steps and commands until told to close,
    or until its parent is gone."""
    parent = mp.parent_process().pid
    # A terminal's Ctrl-C, `timeout` and Slurm's scancel signal the whole process group: the
    # caller stops in order and closes this worker (which also ends if the caller is gone).
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)
    torch.set_num_threads(1)
    try:
        env = LabVecEnv(spec, cfg, backend="cpu", seed=seed, autoreset_mode=mode,
                        shard=(shard.first, total),
                        physics=ShardPhysics(board, index, steals=True))
    except Exception as exc:  # reported by the caller as one line
        conn.send(("error", first_line(exc)))
        return
    conn.send(("ok", None))
    end = _ShardEnd(env, buffers, shard, index)
    flags = buffers["flags"].numpy()[index]
    while True:
        if not _spin_acquire(go):
            _acquire_while_parent_lives(go, parent)
        if not flags[COMMAND]:
            try:
                end.step()
            except Exception as exc:  # sent before `done`: the caller reads it after waiting
                conn.send(("error", _report(exc)))
                flags[FAILED] = 1
            done.release()
            continue
        flags[COMMAND] = 0
        command, args = conn.recv()
        if command == "close":
            env.close()
            return
        try:
            conn.send(("ok", _by_value(end.handle(command, args))))
        except Exception as exc:
            conn.send(("error", _report(exc)))


@dataclass(frozen=True)
class _Copied:
    """A tensor a worker answers with, as its values. A tensor itself would cross as a shared
    memory file that the caller fetches from the worker after the answer arrived (torch's
    reductions: a file descriptor handed over by the worker's resource-sharing thread), and a
    worker stopped (SIGSTOP) in between would leave the caller waiting forever, past any
    check."""

    values: np.ndarray


def _by_value(answer: Any) -> Any:
    """`answer` with every tensor in it (in dicts, lists, tuples) `_Copied`."""
    return _converted(answer, torch.Tensor, lambda tensor: _Copied(tensor.numpy()))


def _as_tensors(answer: Any) -> Any:
    """`_by_value` undone, in the caller."""
    return _converted(answer, _Copied, lambda copied: torch.from_numpy(copied.values))


def _converted(value: Any, kind: type, convert: Callable[[Any], Any]) -> Any:
    """`value` with every `kind` in it (in dicts, lists, tuples) `convert`ed."""
    if isinstance(value, kind):
        return convert(value)
    if isinstance(value, dict):
        return {key: _converted(item, kind, convert) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(_converted(item, kind, convert) for item in value)
    return value


def _spin_acquire(semaphore: Any) -> bool:
    """Take `semaphore` if it is released within `SPIN_S`, polling; False if not (then block)."""
    deadline = time.perf_counter() + SPIN_S
    while not semaphore.acquire(False):
        if time.perf_counter() > deadline:
            return False
    return True


def _acquire_while_parent_lives(semaphore: Any, parent: int) -> None:
    """Take `semaphore`, waking every `ORPHAN_CHECK_S` to see whether the process that
    started this one is still its parent: one killed without a chance to close its shards
    (SIGKILL, the OOM killer) leaves them waiting here, and they end instead."""
    while not semaphore.acquire(timeout=ORPHAN_CHECK_S):
        if os.getppid() != parent:
            os._exit(1)


def _report(exc: BaseException) -> str:
    """An error's one line for the caller, its traceback after it (for a bug's report)."""
    return f"{first_line(exc)}\n{traceback.format_exc()}"


class _ShardEnd:
    """A shard's env and its rows of the shared buffers, in the process that steps it: its
    step, and the commands the caller sends between steps.

    A shard's tensors leave its process only as copies (the caller clones what it returns), so
    it runs in inference mode, without autograd's bookkeeping (~8% of a step of 64 cartpoles);
    its commands too: a task may keep a tensor that a step made and write into it in a reset,
    which fails outside inference mode."""

    def __init__(self, env: LabVecEnv, buffers: dict[str, torch.Tensor], shard: _Shard,
                 index: int):
        rows = slice(shard.first, shard.stop)
        self.env = env
        env.keep_stats_in(buffers["stats"][index])
        # Views made once: slicing each buffer on every step costs as much as copying into it.
        self.actions = buffers["actions"][rows]
        self.outputs = StepOutputs(**{f.name: buffers[f.name][rows] for f in fields(StepOutputs)
                                      if f.name in buffers})
        self.obs = self.outputs.obs

    @torch.inference_mode()
    def step(self) -> None:
        """Step on the shard's rows of the shared actions, its outputs into its rows."""
        self.env.step_into(self.actions, self.outputs)

    @torch.inference_mode()
    def handle(self, command: str, args: Sequence[Any]) -> Any:
        return getattr(self, command)(*args)

    def reset(self, seed: int | None, mask: torch.Tensor | None,
              state: dict[str, Any] | None) -> None:
        if state is not None:
            self.env.resume_from(state)
        options = None if mask is None else {"reset_mask": mask}
        obs, _ = self.env.reset(seed=seed, options=options)
        self.obs.copy_(obs)
        self.env.critic_info(self.outputs.critic_obs)

    def start_staggered(self) -> None:
        self.env.start_staggered()

    def observations(self) -> None:
        self.obs.copy_(self.env.observations())
        self.env.critic_info(self.outputs.critic_obs)

    def get_state(self) -> dict[str, torch.Tensor]:
        return self.env.get_state()

    def set_state(self, state: dict[str, torch.Tensor]) -> None:
        self.env.set_state(state)

    def snapshot(self) -> dict[str, Any]:
        """All a pickled copy of the shard needs (its `__reduce__` state)."""
        return self.env.__reduce__()[2]

    def restore(self, state: dict[str, Any]) -> None:
        self.env.__setstate__(state)


class _Worker:
    def __init__(self, ctx: Any, args: tuple, index: int, flags: np.ndarray):
        self.go, self.done = ctx.Semaphore(0), ctx.Semaphore(0)
        self.conn, theirs = ctx.Pipe()
        self.index, self.flags = index, flags
        self.process = ctx.Process(target=_serve, args=(*args, self.go, self.done, theirs),
                                   name=f"lab-env-shard-{index}", daemon=True)
        with _main_not_rerun():
            self.process.start()
        theirs.close()

    def send(self, command: str, args: tuple = ()) -> None:
        """Have the worker run `command` (a `_ShardEnd` command, or "close") next."""
        with self._gone_if_the_pipe_breaks():
            self.conn.send((command, args))
        self.flags[COMMAND] = 1
        self.go.release()

    def answer(self, check: Callable[[], None] | None = None) -> Any:
        """The worker's reply to the last command; its error as a LabError, as is one from
        `check` while it waits (by default: whether the worker lives)."""
        with self._gone_if_the_pipe_breaks():
            while not self.conn.poll(0.1):
                (check or (lambda: _check_alive([self])))()
            kind, value = self.conn.recv()
        if kind == "error":
            raise LabError(f"env shard {self.index} (a worker process): {value.splitlines()[0]}")
        return _as_tensors(value)

    @contextlib.contextmanager
    def _gone_if_the_pipe_breaks(self) -> Iterator[None]:
        """A pipe that breaks is a worker that died: said as such. Left to rise, a
        BrokenPipeError reads as a closed stdout to the command line, which ends in silence."""
        try:
            yield
        except (BrokenPipeError, ConnectionResetError, EOFError) as exc:
            self.process.join(timeout=5)
            _check_alive([self])
            raise LabError(f"env shard {self.index}'s worker process stopped answering "
                           f"({type(exc).__name__})", "see the lines above it for why") from None

    def wait(self, check: Callable[[], None]) -> None:
        """Until the worker's step is done; a LabError if it failed, or from `check` (a worker
        is gone, each may be stepping chunks of this one's physics; a stop asked for long
        ago)."""
        if not _spin_acquire(self.done):
            while not self.done.acquire(timeout=0.1):
                check()
        if self.flags[FAILED]:  # a step raised: its error is in the pipe
            self.flags[FAILED] = 0
            self.answer(check)


def _check_alive(workers: list[_Worker]) -> None:
    for worker in workers:
        if not worker.process.is_alive():
            raise LabError(f"env shard {worker.index}'s worker process ended (exit code "
                           f"{worker.process.exitcode})", "see the lines above it for why")


@contextlib.contextmanager
def _main_not_rerun() -> Iterator[None]:
    """A spawned process runs the parent's main script again before its target, unless that
    script guards itself with `if __name__ == "__main__"`: a user's unguarded script would start
    its training again in every worker. The worker needs nothing from it (its target and
    arguments import from lab and the task's plugin), so it is not told of the script."""
    main = sys.modules["__main__"]
    saved = {name: main.__dict__[name] for name in ("__spec__", "__file__")
             if name in main.__dict__}
    main.__spec__ = None
    main.__dict__.pop("__file__", None)
    try:
        yield
    finally:
        main.__dict__.update(saved)


def _stop(workers: list[_Worker]) -> None:
    for worker in workers:
        if worker.process.is_alive():
            with contextlib.suppress(LabError, OSError):
                worker.send("close")
    for worker in workers:
        if not _stopped(worker.process.pid):  # a stopped one never closes
            worker.process.join(timeout=5)
        if worker.process.is_alive():
            worker.process.kill()
            worker.process.join()
        worker.conn.close()


def _stopped(pid: int) -> bool:
    """Whether process `pid` is stopped (SIGSTOP, SIGTSTP); False where /proc cannot tell."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "T"
    except (OSError, IndexError):
        return False


class ShardedVecEnv(gym.vector.VectorEnv):
    """`LabVecEnv`'s interface over shards of its envs in processes (see the module's text).
    `sim` and `task` are shard 0's (env 0 and its neighbours): render and the viewer show env 0
    as they do for one process."""

    render_mode = "rgb_array"

    def __init__(self, spec: TaskSpec, cfg: TaskConfig, *, seed: int = 0,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.SAME_STEP,
                 shards: int | None = None):
        """`shards`: how many, a power of two (by default `shard_count`'s, for the config's
        threads on this machine's cores)."""
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        self.task_spec, self.cfg = spec, cfg
        self.num_envs = n = cfg.num_envs
        self.backend, self.device = "cpu", torch.device("cpu")
        self._shards = _layout(n, shards or shard_count(n, cfg.threads))
        self.threads = len(self._shards)

        def shard_cfg(shard: _Shard) -> TaskConfig:
            return cfg.model_copy(update={"num_envs": shard.stop - shard.first, "threads": 1})

        first = self._shards[0]
        ctx = mp.get_context("spawn")
        self._workers: list[_Worker] = []
        self._stop_workers = weakref.finalize(self, _stop, self._workers)
        model, per_env_fields = (spec.task_class.build_model(cfg, spec.model),
                                 spec.task_class.per_env_fields(cfg))
        check_fits(model, n, per_env_fields)
        # A task that writes controls between physics steps (motor models) steps one at a time.
        nstep = 1 if spec.task_class.acts_each_physics_step(cfg) else cfg.decimation
        board = ChunkBoard(ctx, model, [(shard.first, shard.stop) for shard in self._shards],
                           nstep, per_env_fields)
        # Shard 0 first, here: a config the task refuses fails before any process starts.
        self._local = LabVecEnv(
            spec, shard_cfg(first), backend="cpu", seed=seed, autoreset_mode=self.autoreset_mode,
            shard=(0, n), physics=ShardPhysics(board, 0, steals=False, check=self._check))
        self._board = board
        try:
            self._start(spec, seed, board, ctx, shard_cfg)
        except BaseException:
            self.close()
            raise

    def _start(self, spec: TaskSpec, seed: int, board: ChunkBoard, ctx: Any,
               shard_cfg: Callable[[_Shard], TaskConfig]) -> None:
        """All but shard 0's env: the whole env's spaces, the shared buffers, the workers."""
        local, n, first = self._local, self.num_envs, self._shards[0]
        for name in ("metadata", "step_dt", "max_episode_length", "observation_names",
                     "critic_observation_size", "action_names", "single_observation_space",
                     "single_action_space", "clip_actions", "reward_names", "termination_names",
                     "metric_names", "sim", "task"):
            setattr(self, name, getattr(local, name))
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, n)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, n)
        self._rng = EnvRandom(n, "cpu")  # checks a whole env's saved generator states
        self._np_random, self._np_random_seed = gym.utils.seeding.np_random(seed)
        self._resume_state: dict[str, torch.Tensor] | None = None
        self._stepped = False
        self._stop_seen: float | None = None
        self._buffers = _buffers(local, n, len(self._shards))
        self._local_end = _ShardEnd(local, self._buffers, first, 0)
        for i, shard in enumerate(self._shards[1:], start=1):
            self._workers.append(_Worker(ctx, (spec, shard_cfg(shard), seed,
                                               self.autoreset_mode, shard, n, i, self._buffers,
                                               board), i, self._buffers["flags"].numpy()[i]))
        for worker in self._workers:
            worker.answer()

    # gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | Sequence[int] | None = None,
              options: dict[str, Any] | None = None):
        if self.closed:
            raise closed_error("reset", self.task_spec.name)
        if seed is not None:
            seed = self._local.one_seed(seed)
        mask = reset_mask(options, self.num_envs, self.device)  # all checked, then done
        if seed is not None:
            self._np_random, self._np_random_seed = gym.utils.seeding.np_random(seed)
        state = None
        if mask is None:
            state, self._resume_state = self._resume_state, None
        parts = self._split(state) if state is not None else [None] * len(self._shards)
        self._each("reset", *([seed, self._rows(mask, shard), part]
                              for shard, part in zip(self._shards, parts, strict=True)))
        if mask is None:
            self._buffers["stats"].zero_()
        return self._buffers["obs"].clone(), self._critic_info()

    def _critic_info(self) -> dict[str, torch.Tensor]:
        """The shards' critic observations of the last reset or observation, as LabVecEnv's
        `critic_info`."""
        critic = self._buffers.get("critic_obs")
        return {} if critic is None else {"critic_obs": critic.clone()}

    def step(self, actions: torch.Tensor):
        if self.closed:
            raise closed_error("step", self.task_spec.name)
        b = self._buffers
        actions = checked_actions(actions, b["actions"].shape, self.device)
        b["actions"].copy_(actions)
        # A compiled step's first step compiles it: here first, then in the workers from
        # inductor's cache on disk, not in every process at once.
        first = self.cfg.compile and not self._stepped
        self._stepped = True
        with compiling_notice() if first else contextlib.nullcontext():
            self._step_shards(local_first=first)
        return self._local.returned(StepOutputs(**{f.name: b[f.name].clone()
                                                   for f in fields(StepOutputs) if f.name in b}))

    def _step_shards(self, local_first: bool) -> None:
        """Every shard's step, the workers' released before or after this process's own."""
        if not local_first:
            for worker in self._workers:
                worker.go.release()
        # Whatever happens here (an error, Ctrl-C), every worker finishes this step before the
        # step ends: a worker left behind would answer the next step with this one.
        failure: BaseException | None = None
        try:
            self._local_end.step()
        except BaseException as exc:
            failure = exc
        if local_first:
            for worker in self._workers:
                worker.go.release()
        for worker in self._workers:
            while True:
                try:
                    worker.wait(self._check)
                except KeyboardInterrupt as exc:  # wait on: the worker is still stepping
                    failure = failure or exc
                    continue
                except LabError as exc:  # the worker's step failed, or the worker is gone
                    failure = failure or exc
                break
        if failure is not None:
            raise failure

    def interrupted(self) -> bool:
        """Whether the run stepping this env was asked to stop (a training run replaces this
        with its stop request): a step that waits on a worker then gives up after
        `STOP_GRACE_S`, rather than forever on one that was stopped (SIGSTOP)."""
        return False

    def _check(self) -> None:
        """Called while the caller waits on the workers: a LabError if one is gone, or if a
        stop was asked STOP_GRACE_S ago and they still step."""
        _check_alive(self._workers)
        if not self.interrupted():
            return
        now = time.monotonic()
        self._stop_seen = self._stop_seen or now
        if now - self._stop_seen > STOP_GRACE_S:
            stopped = [f"{w.index} (pid {w.process.pid})" for w in self._workers
                       if _stopped(w.process.pid)]
            raise LabError(f"the env's shards did not answer {STOP_GRACE_S:g} s "
                           "after the stop was asked" + (
                               f": worker of shard {', '.join(stopped)} is stopped (SIGSTOP)"
                               if stopped else ""), "the run keeps its last checkpoint")

    def close_extras(self, **kwargs: Any) -> None:
        self._stop_workers()
        self._local.close()

    # what LabVecEnv offers besides -----------------------------------------------------------
    def render(self) -> np.ndarray:
        return self._local.render()

    def mj_scene(self):
        return self._local.mj_scene()

    def markers(self) -> list:
        return self._local.markers()

    def describe(self) -> dict[str, Any]:
        return self._local.describe()

    def observations(self) -> torch.Tensor:
        self._each("observations")
        return self._buffers["obs"].clone()

    def pop_stats(self, reduce: Reduce | None = None) -> dict[str, float]:
        totals = self._buffers["stats"].sum(dim=0)
        self._buffers["stats"].zero_()
        return self._local.summarize_stats(totals if reduce is None else reduce(totals))

    def get_state(self) -> dict[str, torch.Tensor]:
        parts = self._each("get_state")
        return {name: torch.cat([part[name] for part in parts]) for name in parts[0]}

    def check_state(self, state: Any) -> None:
        self._local.check_state(state, num_envs=self.num_envs, rng=self._rng)

    def set_state(self, state: dict[str, torch.Tensor]) -> None:
        self._each("set_state", *([part] for part in self._split(state)))

    def resume_from(self, state: dict[str, torch.Tensor]) -> None:
        self._resume_state = state

    def start_staggered(self) -> None:
        self._each("start_staggered")

    def __reduce__(self):
        # Worker processes do not pickle: a copy is built anew and put in this one's state.
        return (_rebuilt, (self.task_spec, self.cfg, self.autoreset_mode, len(self._shards)),
                {"shards": self._each("snapshot"), "stats": self._buffers["stats"].clone(),
                 "np_random": self._np_random.bit_generator.state,
                 "np_random_seed": self._np_random_seed})

    def __setstate__(self, state: dict[str, Any]) -> None:
        self._each("restore", *([part] for part in state["shards"]))
        self._buffers["stats"].copy_(state["stats"])
        self._np_random.bit_generator.state = state["np_random"]
        self._np_random_seed = state["np_random_seed"]

    @property
    def episode_length(self) -> torch.Tensor:
        """Every env's steps in its episode so far (a copy: gathered from the shards)."""
        return self.get_state()["episode_length"]

    # internals -------------------------------------------------------------------------------
    def _each(self, command: str, *args_per_shard: Sequence[Any]) -> list[Any]:
        """Run a `_ShardEnd` command on every shard (here and in the workers at once); their
        answers in shard order. `args_per_shard[i]`: shard i's arguments (none if left out)."""
        args = list(args_per_shard) or [()] * len(self._shards)
        for worker, worker_args in zip(self._workers, args[1:], strict=True):
            worker.send(command, tuple(worker_args))
        mine = self._local_end.handle(command, args[0])
        return [mine, *(worker.answer(self._check) for worker in self._workers)]

    def _split(self, state: dict[str, torch.Tensor]) -> list[dict[str, torch.Tensor]]:
        """A whole env's state cut into each shard's."""
        self.check_state(state)
        return [{name: (value[shard.blocks] if name == "generator"
                        else value[shard.first:shard.stop]) for name, value in state.items()}
                for shard in self._shards]

    @staticmethod
    def _rows(mask: torch.Tensor | None, shard: _Shard) -> torch.Tensor | None:
        return None if mask is None else mask[shard.first:shard.stop].clone()


def _rebuilt(spec: TaskSpec, cfg: TaskConfig, autoreset_mode: AutoresetMode,
             shards: int) -> ShardedVecEnv:
    return ShardedVecEnv(spec, cfg, autoreset_mode=autoreset_mode, shards=shards)
