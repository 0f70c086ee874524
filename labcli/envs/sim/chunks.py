"""The physics of the cpu backend's env shards in chunks that another shard's process may step.

A shard's process steps its envs' physics and then their task code; all shards end a step
together, so the step lasts as long as the slowest shard. On a 16-core host, shards of the same
work took 1,408–2,065 µs a step (cartpole, 128 envs each; each process stayed on its core): the
cores do not run equally fast. So each shard's physics is cut into `CHUNKS` chunks, and the
state, controls and results of all envs live in shared memory: a worker process that has stepped
its own chunks steps a slower shard's chunks that nobody has started, from the last one back,
before it goes on to its own task code. Which process steps an env does not change its physics
(MuJoCo is deterministic, and `rollout` starts each env from its state with a zero warm start),
so outputs stay those of one process.

Each chunk has a lock that its shard's process releases at the start of the step ("open"):
whoever takes it steps the chunk. A shard counts the chunks others stepped for it on its `done`
semaphore. The calling process's shard opens its chunks but takes none of the others': Ctrl-C
lands in that process, and between taking a chunk and stepping it, it would leave its owner
waiting forever. Where a task varies model fields per env (masses, friction), their values are
in shared memory too, and a process writes them into its own models before it steps another
shard's envs.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import torch
from mujoco import rollout

from labcli.envs.sharedmem import shared

FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
# Equal chunks per shard: more balance finer, but each is one more `rollout` call (~2 µs on a
# VM; cartpole, 128 envs: 362 µs a step in one call, 379 µs in four of 32 envs). Chunks of 1/2,
# 1/4, 1/8, 1/16 and 1/16 of a shard were no better on 16 cores.
CHUNKS = 4
# How long a shard waits for the chunks others step before it checks that they are alive.
CHECK_S = 0.1


class ChunkBoard:
    """The shared side: every env's physics arrays in shared memory, and per shard the locks of
    its chunks and the count of those that others stepped. Made once by the whole env and
    handed to every shard's process (its semaphores and tensors pickle for `spawn`)."""

    def __init__(self, ctx: Any, model: mujoco.MjModel, shards: list[tuple[int, int]],
                 nstep: int, per_env_fields: Sequence[str] = ()):
        n = shards[-1][1]
        nstate = mujoco.mj_stateSize(model, FULL)
        self.nstep = nstep
        self.state = shared(torch.zeros(n, nstate, dtype=torch.float64))
        self.controls = shared(torch.zeros(n, nstep, model.nu, dtype=torch.float64))
        self.out = shared(torch.zeros(n, nstep, nstate, dtype=torch.float64))
        self.sensors = shared(torch.zeros(n, nstep, model.nsensordata, dtype=torch.float64))
        # The model's fields that vary per env, each env's values (`Sim.model_field`).
        self.fields = {name: shared(torch.from_numpy(np.stack([getattr(model, name)] * n)))
                       for name in per_env_fields}
        # [thief, shard]: chunks of a shard that another process stepped (each row written by
        # its thief alone), to see that stealing happens.
        self.stolen = shared(torch.zeros(len(shards), len(shards), dtype=torch.long))
        self.chunks = [[first + c * (stop - first) // CHUNKS for c in range(CHUNKS + 1)]
                       for first, stop in shards]
        self.open = [[ctx.Lock() for _ in range(CHUNKS)] for _ in shards]
        for locks in self.open:  # closed until their shard's step opens them
            for lock in locks:
                lock.acquire()
        self.done = [ctx.Semaphore(0) for _ in shards]

    def rows(self, shard: int) -> slice:
        bounds = self.chunks[shard]
        return slice(bounds[0], bounds[-1])


@dataclass
class ShardPhysics:
    """What a shard's `CpuSim` steps with: the board, its shard's index, whether it takes
    others' chunks, and the check of `ChunkStepper`."""

    board: ChunkBoard
    shard: int
    steals: bool
    check: Callable[[], None] = lambda: None


class ChunkStepper:
    """One process's side: steps its shard's physics (its chunks, and waits for those others
    took) and, if `steals`, slower shards' untaken chunks. `check` raises if a process that may
    be stepping this shard's chunks is gone (else the wait would never end)."""

    def __init__(self, physics: ShardPhysics, model: mujoco.MjModel,
                 models: list[mujoco.MjModel]):
        """`models`: the MjModel of each of this shard's envs (`CpuSim.models`)."""
        board, shard = physics.board, physics.shard
        self.board, self.shard, self.steals = board, shard, physics.steals
        self.check = physics.check
        self._runner = rollout.Rollout(nthread=0)
        self._data = [mujoco.MjData(model)]
        self._own, self._first = models, board.chunks[shard][0]
        size = max(b[c + 1] - b[c] for b in board.chunks for c in range(CHUNKS))
        # Another shard's envs step on this process's model, or where fields vary per env on
        # copies of it that take those envs' values first.
        self._others = ([copy.copy(model) for _ in range(size)] if board.fields
                        else [model] * size)
        self._fields = {name: values.numpy() for name, values in board.fields.items()}
        # This process's row of the count, as numpy: a torch index and add would cost more than
        # the lock a steal takes.
        self._stolen = board.stolen.numpy()[shard]
        arrays = (board.state, board.controls, board.out, board.sensors)
        self._state, self._controls, self._out, self._sensors = (a.numpy() for a in arrays)
        self._order = [(s, c) for s in [*range(shard + 1, len(board.chunks)), *range(shard)]
                       for c in reversed(range(CHUNKS))]

    def step(self) -> None:
        """Step this shard's physics: `board.controls` of its rows in, `board.out` out."""
        open_, done = self.board.open[self.shard], self.board.done[self.shard]
        while done.acquire(False):  # counts left by a step that Ctrl-C broke
            pass
        for lock in open_:
            lock.acquire(False)  # one a broken step left open: released once only
            lock.release()
        mine = 0
        try:
            for chunk, lock in enumerate(open_):
                if lock.acquire(False):
                    self._roll(self.shard, chunk)
                    mine += 1
            if self.steals:
                self._steal()
            for _ in range(CHUNKS - mine):
                self._wait(done)
        finally:
            for lock in open_:  # none stays open for a process to take after this step
                lock.acquire(False)

    def _steal(self) -> None:
        for shard, chunk in self._order:
            if self.board.open[shard][chunk].acquire(False):
                try:
                    self._roll(shard, chunk)
                finally:
                    self.board.done[shard].release()
                self._stolen[shard] += 1

    def _roll(self, shard: int, chunk: int) -> None:
        bounds = self.board.chunks[shard]
        rows = slice(bounds[chunk], bounds[chunk + 1])
        count = rows.stop - rows.start
        if not count:  # a shard of fewer envs than chunks
            return
        if shard == self.shard:
            models = self._own[rows.start - self._first:rows.stop - self._first]
        else:
            models = self._others[:count]
            for name, values in self._fields.items():
                for model, value in zip(models, values[rows], strict=True):
                    getattr(model, name)[:] = value
        self._runner.rollout(models, self._data, self._state[rows],
                             self._controls[rows], nstep=self.board.nstep, state=self._out[rows],
                             sensordata=self._sensors[rows], skip_checks=True, chunk_size=count)

    def _wait(self, done: Any) -> None:
        deadline = time.perf_counter() + CHECK_S
        while not done.acquire(False):  # a chunk takes µs to ms: poll, as the shards do
            if time.perf_counter() > deadline:
                if done.acquire(timeout=CHECK_S):
                    return
                self.check()

    def close(self) -> None:
        self._runner.close()
