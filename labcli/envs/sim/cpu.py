"""CPU backend: MuJoCo's C engine steps the envs with `mujoco.rollout`: on two threads the
calling thread and one worker thread, each its share of them; on more, MuJoCo's thread pool; in
an env shard, its process in chunks that other shards' processes may step too (`chunks.py`)."""

from __future__ import annotations

import copy
import math
import threading
import time
import weakref
from collections.abc import Callable, Sequence

import mujoco
import numpy as np
import torch
from mujoco import rollout

from labcli.envs.cores import available_memory, cores, gib
from labcli.envs.sim import Sim
from labcli.envs.sim.chunks import ChunkStepper, ShardPhysics
from labcli.errors import LabError

FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS


def _state_slice(model: mujoco.MjModel, part: mujoco.mjtState) -> slice:
    """Where `part` lies inside a full-physics state vector (components are in bit order)."""
    start = sum(
        mujoco.mj_stateSize(model, bit)
        for bit in (1 << i for i in range(mujoco.mjtState.mjNSTATE.value))
        if bit < part.value and bit & FULL.value
    )
    return slice(start, start + mujoco.mj_stateSize(model, part))


def check_fits(model: mujoco.MjModel, num_envs: int, per_env_fields: Sequence[str]) -> None:
    """Refuse envs whose physics cannot fit in the memory the host has left, in one line:
    MuJoCo would fail deep in an allocation, or the OS would kill the process. The state arrays
    hold a few vectors an env; where model fields vary per env, each env has a copy of the
    model (rollout takes a model an env), which dominates."""
    vectors = mujoco.mj_stateSize(model, FULL) + model.nu + model.nsensordata
    per_env = 3 * 8 * vectors + (model.nbuffer if per_env_fields else 0)
    free = available_memory()
    if free is None or num_envs * per_env <= free:
        return
    why = (f", a copy of the model each, for per-env {', '.join(per_env_fields)}"
           if per_env_fields else "")
    raise LabError(f"env.num_envs={num_envs:,} needs about {gib(num_envs * per_env)} for the "
                   f"cpu backend's physics ({gib(per_env)} an env{why}), more than the "
                   f"{gib(free)} free", f"use at most {free // per_env:,} envs")


class _Worker:
    """A thread that runs one job per `start()` while the caller works too; `wait()` returns
    when it is done and re-raises what it raised. Two plain locks: a step lasts a few hundred
    µs, and a `concurrent.futures` future's bookkeeping made it ~6% slower at 256 envs."""

    def __init__(self, name: str):
        self._go, self._done = threading.Lock(), threading.Lock()
        self._go.acquire()
        self._done.acquire()
        self._job: Callable[[], None] | None = None
        self._error: BaseException | None = None
        self._closed = False
        self.finished_at = 0.0  # perf_counter when the last job ended
        self._thread = threading.Thread(target=self._serve, name=name, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while True:
            self._go.acquire()
            if self._closed:
                return
            try:
                self._job()
            except BaseException as error:  # handed to the caller by wait()
                self._error = error
            self.finished_at = time.perf_counter()
            self._done.release()

    def start(self, job: Callable[[], None]) -> None:
        self._job = job
        self._go.release()

    def wait(self) -> None:
        try:
            self._done.acquire()
        except BaseException:  # KeyboardInterrupt from a signal: the job still writes the state
            self._done.acquire()
            raise
        finally:
            self._job = None  # it holds the sim: dropped, so an unclosed sim can be collected
        error, self._error = self._error, None
        if error is not None:
            raise error

    def close(self) -> None:
        self._closed = True
        self._go.release()
        if threading.current_thread() is not self._thread:  # a finalizer runs on any thread
            self._thread.join()


class CpuSim(Sim):
    """The state of all envs is one numpy array (torch views of it are `qpos`, `qvel`); each step
    is one `mujoco.rollout` of `nstep` physics steps from it.

    On two threads (an env too small to shard: `labcli.envs.shards.shard_count`), the calling
    thread steps a share of the envs itself beside one worker thread, rather than sleeping
    while MuJoCo's pool steps them all: a pool wakes its threads and then
    the caller each step, and on a VM such wake-ups are slow and uneven (cartpole, 256 envs, 2
    cores: `sim.step` took 495–538 µs on average with the pool, 90th percentile 519–881 µs;
    474–476 µs and 506–511 µs this way). The share is balanced each step (see `step`). On more
    threads MuJoCo's pool steps all envs: handing the others' share on to a pool from the worker
    thread adds a hop of its own, and one caller's share matters less (16 cores: the pool alone
    was 3–15% faster at 1,024 and 4,096 envs; at 4 and 8 threads mixed, 0.85–1.23 of it)."""

    def __init__(self, model: mujoco.MjModel, num_envs: int, nthread: int | None = None,
                 per_env_fields: Sequence[str] = (), shard: ShardPhysics | None = None):
        """`shard`: this sim is an env shard's, its physics arrays rows of `shard.board`'s and
        stepped in chunks (`labcli.envs.sim.chunks`); on one thread."""
        # MuJoCo's own reset of a diverged state would hide it from `Sim.unstable()`: lab resets
        # such envs itself, and counts them. On a copy: the caller's model may also go to MuJoCo
        # Warp, which has no such reset and refuses the flag.
        if shard is None:  # a sharded env checked all its shards' envs
            check_fits(model, num_envs, per_env_fields)
        model = copy.copy(model)
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
        self.model = model
        self.num_envs = num_envs
        self.device = torch.device("cpu")
        self.nthread = min(nthread or cores(), num_envs)
        # One MjModel per env where a field differs per env (rollout takes one per env).
        self._models = ([copy.copy(model) for _ in range(num_envs)] if per_env_fields
                        else [model] * num_envs)
        self._fields = ({name: torch.from_numpy(np.stack([getattr(model, name)] * num_envs))
                         for name in per_env_fields} if shard is None else
                        {name: shard.board.fields[name][shard.board.rows(shard.shard)]
                         for name in per_env_fields})
        pool = self.nthread if self.nthread > 2 else 0  # 0: on the calling thread
        # An env shard's physics steps through its `ChunkStepper` instead.
        self._mine = rollout.Rollout(nthread=pool) if shard is None else None
        self._my_data = [mujoco.MjData(model) for _ in range(max(pool, 1))]
        # Envs [0, split) are the calling thread's, the rest the worker thread's.
        self._split = num_envs
        self._theirs: rollout.Rollout | None = None
        self._worker: _Worker | None = None
        self._stop_worker = None
        if self.nthread == 2:
            self._theirs = rollout.Rollout(nthread=0)
            self._their_data = [mujoco.MjData(model)]
            self._worker = _Worker("lab-physics")
            # The worker's thread stops when the sim is closed, or collected unclosed.
            self._stop_worker = weakref.finalize(self, self._worker.close)
            self._split = num_envs // 2
            self._balance_step = max(1, num_envs // 128)

        data = self._my_data[0]
        mujoco.mj_resetData(model, data)
        nstate = mujoco.mj_stateSize(model, FULL)
        self._default = np.empty(nstate)
        mujoco.mj_getState(model, data, self._default, FULL)
        self._chunks: ChunkStepper | None = None
        if shard is None:
            self._state = np.empty((num_envs, nstate))
            self._out: np.ndarray | None = None
        else:
            rows = shard.board.rows(shard.shard)
            self._state = shard.board.state.numpy()[rows]
            self._out = shard.board.out.numpy()[rows]
            self._ctrl_steps = shard.board.controls.numpy()[rows]
            self._sensors = shard.board.sensors.numpy()[rows]
            self._chunks = ChunkStepper(shard, model, self._models)
        self._state[:] = self._default
        self._ctrl = np.zeros((num_envs, model.nu))
        self._sensordata = np.zeros((num_envs, model.nsensordata))

        # torch views of the numpy arrays, sharing their memory: MuJoCo and torch see one state.
        self._state_t = torch.from_numpy(self._state)
        self._default_t = torch.from_numpy(self._default)
        self.qpos = self._state_t[:, _state_slice(model, mujoco.mjtState.mjSTATE_QPOS)]
        self.qvel = self._state_t[:, _state_slice(model, mujoco.mjtState.mjSTATE_QVEL)]
        self.ctrl = torch.from_numpy(self._ctrl)
        self.sensordata = torch.from_numpy(self._sensordata)

    def step(self, nstep: int, controls: torch.Tensor | None = None,
             substep: Callable[[int], None] | None = None) -> None:
        if substep is None:
            self._physics(nstep, controls)
            return
        for k in range(nstep):  # one rollout a physics step, the controls written between
            substep(k)
            self._physics(1, None)

    def _physics(self, nstep: int, controls: torch.Tensor | None) -> None:
        if self._chunks is not None and nstep != self._chunks.board.nstep:
            raise ValueError(f"an env shard's sim steps {self._chunks.board.nstep} physics "
                             f"steps at a time, not {nstep}")
        if self._out is None or self._out.shape[1] != nstep:
            n = self.num_envs
            self._out = np.empty((n, nstep, self._state.shape[1]))
            self._ctrl_steps = np.empty((n, nstep, self.model.nu))
            self._sensors = np.empty((n, nstep, self.model.nsensordata))
        if controls is None:  # zero-order hold: the same ctrl for every physics substep
            self._ctrl_steps[:] = self._ctrl[:, None, :]
        else:
            self._ctrl_steps[:] = controls.numpy().transpose(1, 0, 2)
            self._ctrl[:] = self._ctrl_steps[:, -1]
        split = self._split
        if self._chunks is not None:
            self._chunks.step()
        elif self._worker is None:
            self._roll(self._mine, self._my_data, 0, split, nstep)
        else:
            self._worker.start(lambda: self._roll(self._theirs, self._their_data, split,
                                                  self.num_envs, nstep))
            try:
                self._roll(self._mine, self._my_data, 0, split, nstep)
                mine_finished_at = time.perf_counter()
            finally:
                self._worker.wait()
            # Envs move to the side that finished first: three steps' worth toward this thread
            # when it waited, one toward the worker when the worker idled. Waiting costs a
            # wake-up on top of the gap (~20 µs on a VM), so the balance settles where the
            # worker ends first in three steps of four, not at an even split.
            if mine_finished_at < self._worker.finished_at:
                self._split = min(split + 3 * self._balance_step, self.num_envs - 1)
            else:
                self._split = max(split - self._balance_step, 1)
        self._state[:] = self._out[:, -1]
        if self.model.nsensordata:
            self._sensordata[:] = self._sensors[:, -1]

    def _roll(self, runner: rollout.Rollout, datas: list[mujoco.MjData], start: int, stop: int,
              nstep: int) -> None:
        envs = slice(start, stop)
        # One chunk of envs per thread: rollout's default, ten per thread, balances the load
        # but costs more in handing out chunks than it saves (at 64 cartpole envs on 2 cores,
        # the pool's cost over stepping on the calling thread fell from +360 to +60 µs).
        runner.rollout(self._models[envs], datas, self._state[envs], self._ctrl_steps[envs],
                       nstep=nstep, state=self._out[envs], sensordata=self._sensors[envs],
                       skip_checks=True, chunk_size=-(-(stop - start) // len(datas)))

    @property
    def models(self) -> list[mujoco.MjModel]:
        """The MjModel each env steps with (one object for all, unless fields vary per env)."""
        return self._models

    def physics_state(self) -> np.ndarray:
        """A copy of every env's full physics state `[num_envs, mj_stateSize(FULLPHYSICS)]`."""
        return self._state.copy()

    def reset_to_defaults(self, mask: torch.Tensor) -> None:
        # One `where` written straight into the state (out=): faster here than numpy's
        # boolean-mask assignment, which first finds the masked rows.
        torch.where(mask[:, None], self._default_t, self._state_t, out=self._state_t)
        if self.model.nsensordata:
            self.sensordata.masked_fill_(mask[:, None], 0.0)

    def any_unstable(self) -> bool:
        # One reduction over all envs, not a row each: the largest speed (NaN if any is NaN).
        return not float(torch.linalg.vector_norm(self.qvel, ord=math.inf)) < self.unstable_velocity

    def model_field(self, name: str) -> torch.Tensor:
        if name not in self._fields:
            return super().model_field(name)
        return self._fields[name]

    def model_changed(self, name: str, mask: torch.Tensor) -> None:
        values = self._fields[name].numpy()
        for env in mask.nonzero()[:, 0].tolist():  # on the CPU, a host sync is free
            getattr(self._models[env], name)[:] = values[env]

    def close(self) -> None:
        if self._stop_worker is not None:
            self._stop_worker()  # a finalizer runs once: closing twice is harmless
        self._worker = None  # a step after close then fails in the closed rollout, not hangs
        for runner in (self._mine, self._theirs, self._chunks):
            if runner is not None:
                runner.close()
