"""The cpu backend's env shards: processes that step as one env, with the same outputs whatever
their number, and state that moves between sharded and unsharded envs."""

from __future__ import annotations

import copy
import dataclasses
import multiprocessing
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import pytest
import torch
from conftest import needs_menagerie
from lab_cartpole.cartpole import Cartpole

from labcli.envs import metrics
from labcli.envs import shards as shards_module
from labcli.envs.env import EPISODE, LabVecEnv
from labcli.envs.make import make_env
from labcli.envs.random import EnvRandom
from labcli.envs.shards import ShardedVecEnv, shard_count
from labcli.envs.sim.chunks import ChunkBoard, ChunkStepper, ShardPhysics
from labcli.errors import LabError
from labcli.plugins import registry


def build(task: str, num_envs: int, shards: int | None = None, **cfg) -> LabVecEnv:
    spec = registry.get_task(task)
    config = spec.config_class(num_envs=num_envs, **cfg)
    if shards is None:
        return LabVecEnv(spec, config, backend="cpu", seed=0)
    return ShardedVecEnv(spec, config, seed=0, shards=shards)


def trajectory(env, steps: int, seed: int = 5) -> list[torch.Tensor]:
    """Every output of a reset and `steps` steps of seeded random actions, flattened."""
    obs, info = env.reset(seed=seed)
    gen = torch.Generator().manual_seed(seed)
    out = [obs, *info.values()]
    for _ in range(steps):
        action = torch.rand(env.action_space.shape, generator=gen) * 2 - 1
        obs, reward, terminated, truncated, info = env.step(action)
        out += [obs, reward, terminated, truncated, info["terminations"], info[f"_{EPISODE}"],
                *info[EPISODE].values(),
                *(info[key] for key in ("final_obs", "critic_obs", "final_critic_obs")
                  if key in info)]
    return out


def assert_same(a: list[torch.Tensor], b: list[torch.Tensor]) -> None:
    assert len(a) == len(b)
    for i, (x, y) in enumerate(zip(a, b, strict=True)):
        assert x.dtype == y.dtype and torch.equal(x, y), f"output {i} differs"


@pytest.mark.parametrize("task, num_envs, mode, steps, cfg", [
    ("cartpole", 128, "same_step", 400, {}),  # episodes end and reset in every shard
    ("cartpole", 128, "next_step", 200, {}),
    # Draws every step (observation noise, pushes) and on resets: time-outs every 15 steps;
    # each physics step's own control (a motor's latency); the critic's observations.
    pytest.param("go1-flat", 64, "same_step", 40,
                 {"episode_length_s": 0.3, "actions": {"scale": 0.25, "delay": (1, 7)},
                  "critic_observations": "noise_free"},
                 marks=needs_menagerie("unitree_go1")),
    # The critic's own terms: the feet's contacts and air times carried in every shard.
    pytest.param("g1-flat", 32, "same_step", 30,
                 {"episode_length_s": 0.3, "critic_observations": "privileged"},
                 marks=needs_menagerie("unitree_g1")),
])
def test_shards_give_the_outputs_of_one_env(task, num_envs, mode, steps, cfg):
    spec = registry.get_task(task)
    cfg = spec.config_class(num_envs=num_envs, threads=2, **cfg)
    one = LabVecEnv(spec, cfg, backend="cpu", seed=0, autoreset_mode=mode)
    expected, expected_stats = trajectory(one, steps), one.pop_stats()
    one.close()
    for count in (2, 4):
        env = ShardedVecEnv(spec, cfg, seed=0, autoreset_mode=mode, shards=count)
        try:
            assert_same(trajectory(env, steps), expected)
            # Summed per shard, then over shards: the last bits may round differently.
            assert env.pop_stats() == pytest.approx(expected_stats, rel=1e-12)
        finally:
            env.close()
    assert expected_stats[metrics.EPISODES] > 0  # envs ended and reset, in every shard's rows


@pytest.mark.parametrize("task, num_envs, steps, cfg", [
    ("cartpole", 256, 60, {}),
    # Masses and centres of mass drawn per env: a worker steps the caller's envs on its own
    # models with their values.
    pytest.param("go1-flat", 64, 30, {"episode_length_s": 0.3},
                 marks=needs_menagerie("unitree_go1")),
])
def test_workers_step_a_slow_shards_physics_and_the_outputs_stay_one_envs(
        monkeypatch, task, num_envs, steps, cfg):
    """The caller's shard steps its chunks slowly (here only: workers are other processes), so
    the workers take its untaken chunks; every output is still one process's."""
    spec = registry.get_task(task)
    cfg = spec.config_class(num_envs=num_envs, **cfg)
    one = LabVecEnv(spec, cfg, backend="cpu", seed=0)
    expected = trajectory(one, steps)
    one.close()
    roll = ChunkStepper._roll

    def slow_roll(self, shard, chunk):
        time.sleep(0.01)
        roll(self, shard, chunk)

    monkeypatch.setattr(ChunkStepper, "_roll", slow_roll)
    env = ShardedVecEnv(spec, cfg, seed=0, shards=2)
    try:
        assert_same(trajectory(env, steps), expected)
        stolen = env._board.stolen
        assert stolen[1, 0] > 0 and stolen[0].sum() == 0  # the caller takes no chunk
    finally:
        env.close()


def test_ctrl_c_inside_the_callers_physics_leaves_no_chunk_behind(monkeypatch):
    """Ctrl-C while the caller steps a chunk of its physics: the step raises it once every
    worker is done, and the next steps neither hang nor count what the broken step left."""
    spec = registry.get_task("cartpole")
    env = ShardedVecEnv(spec, spec.config_class(num_envs=256), seed=0, shards=2)
    roll, armed = ChunkStepper._roll, []

    def interrupted_roll(self, shard, chunk):
        if armed and armed.pop():  # the caller's first chunk after arming
            raise KeyboardInterrupt
        roll(self, shard, chunk)

    monkeypatch.setattr(ChunkStepper, "_roll", interrupted_roll)
    try:
        env.reset(seed=0)
        env.step(torch.zeros(256, 1))
        armed.append(True)
        with pytest.raises(KeyboardInterrupt):
            env.step(torch.zeros(256, 1))
        for _ in range(3):
            obs, *_ = env.step(torch.zeros(256, 1))
        lengths = env.get_state()["episode_length"]
        assert (lengths[:128] == 4).all() and (lengths[128:] == 5).all()  # the caller lost one
        assert torch.isfinite(obs).all()
    finally:
        env.close()


def test_a_broken_step_leaves_no_chunk_open_nor_count_behind(monkeypatch):
    """The board's protocol, in one process: after a step that Ctrl-C broke before it took its
    chunks, no other process takes one, and a late count of a stolen chunk is not read as this
    step's."""
    spec = registry.get_task("cartpole")
    model = spec.task_class.build_model(spec.config_class(), spec.model)
    board = ChunkBoard(multiprocessing.get_context("spawn"), model, [(0, 64), (64, 128)], 2)
    caller = ChunkStepper(ShardPhysics(board, 0, steals=False), model, [model] * 64)
    worker = ChunkStepper(ShardPhysics(board, 1, steals=True), model, [model] * 64)
    roll = ChunkStepper._roll

    def interrupted_roll(self, shard, chunk):
        if self is caller:
            raise KeyboardInterrupt
        roll(self, shard, chunk)

    monkeypatch.setattr(ChunkStepper, "_roll", interrupted_roll)
    with pytest.raises(KeyboardInterrupt):
        caller.step()
    worker.step()
    assert board.stolen.sum() == 0  # the broken step's chunks were closed, not left to take
    monkeypatch.setattr(ChunkStepper, "_roll", roll)
    board.done[0].release()  # a thief's count that arrives after its step broke
    caller.step()
    assert not board.done[0].acquire(False)  # read at the start of the step, not as its own
    for stepper in (caller, worker):
        stepper.close()


SHRUNK_SHM = """
import sys
from labcli.envs.shards import ShardedVecEnv
from labcli.errors import LabError
from labcli.plugins import registry
spec = registry.get_task("cartpole")
try:
    ShardedVecEnv(spec, spec.config_class(num_envs=int(sys.argv[1])), shards=2)
except LabError as exc:
    print(exc)
"""


def _can_shrink_shm() -> bool:
    return shutil.which("unshare") is not None and subprocess.run(
        ["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=1m tmpfs /dev/shm"],
        capture_output=True).returncode == 0


@pytest.mark.skipif(not _can_shrink_shm(), reason="needs to mount a small /dev/shm in a mount "
                    "namespace of its own (unshare -m, as root)")
@pytest.mark.parametrize("num_envs", [65_536, 49_152])  # full at the chunk board, at the buffers
def test_a_full_shared_memory_is_one_line(num_envs):
    """/dev/shm as small as a container's (a tmpfs of 8 MiB in a mount namespace of its own)."""
    script = (f"mount -t tmpfs -o size=8m tmpfs /dev/shm && {sys.executable} -c "
              f"'{SHRUNK_SHM}' {num_envs}")
    out = subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert re.match(r"the env shards' tensors do not fit in shared memory \(/dev/shm: "
                    r"[\d.]+ MiB free of 8 MiB\)", out.stdout), out.stdout
    assert "docker run --shm-size" in out.stdout and out.stdout.count("\n") == 1


@pytest.fixture
def sharded():
    """128 cartpole envs in 2 shards (closed after the test)."""
    env = build("cartpole", 128, shards=2)
    yield env
    env.close()


def test_state_moves_between_sharded_and_unsharded_envs(sharded):
    trajectory(sharded, 150)
    saved = sharded.get_state()
    one = build("cartpole", 128)
    one.set_state(saved)
    gen = torch.Generator().manual_seed(1)
    twin = copy.deepcopy(sharded)  # a pickled copy: rebuilt, then put in the same state
    try:
        for _ in range(150):
            action = torch.rand(128, 1, generator=gen) * 2 - 1
            outs = [env.step(action) for env in (sharded, one, twin)]
            for out in outs[1:]:
                assert torch.equal(out[0], outs[0][0]) and torch.equal(out[1], outs[0][1])
                assert torch.equal(out[4][f"_{EPISODE}"], outs[0][4][f"_{EPISODE}"])
        assert sharded.pop_stats() == twin.pop_stats()
    finally:
        twin.close()
        one.close()
    with pytest.raises(LabError, match="'qpos' is \\(64, 2\\), this env's \\(128, 2\\)"):
        sharded.set_state({**saved, "qpos": saved["qpos"][:64]})
    # A checkpoint of a lab from before the blocks: one generator's state.
    with pytest.raises(LabError, match="one random generator for all envs"):
        sharded.set_state({**saved, "generator": torch.Generator().get_state()})


def test_reset_mask_observations_and_resume_reach_every_shard(sharded):
    sharded.reset(seed=3)
    before = sharded.observations()
    mask = torch.zeros(128, dtype=torch.bool)
    mask[[5, 100]] = True  # one env in each shard
    obs, _ = sharded.reset(options={"reset_mask": mask})
    changed = (obs != before).any(dim=1)
    assert changed[[5, 100]].all() and not changed[~mask].any()
    assert torch.equal(sharded.observations(), obs)
    state = sharded.get_state()
    trajectory(sharded, 20)
    sharded.resume_from(state)
    obs, _ = sharded.reset()  # the library's first reset continues the saved episodes
    assert torch.equal(obs, before.where(~mask[:, None], obs))
    assert torch.equal(sharded.episode_length, state["episode_length"])


def test_a_worker_s_answers_hold_their_values_not_shared_memory_to_fetch(sharded,
                                                                          monkeypatch):
    """A tensor crossing as shared memory is fetched from the worker after its answer arrived:
    a worker stopped (SIGSTOP) in between hung the caller past every check. Here fetching one
    fails: the state and a pickled copy's snapshot come by value."""
    from torch.multiprocessing import reductions

    def fetched(*args):
        raise AssertionError("a tensor was fetched from a worker")

    trajectory(sharded, 5)
    monkeypatch.setattr(reductions, "rebuild_storage_fd", fetched)
    state = sharded.get_state()
    assert state["qpos"].shape == (128, 2) and state["generator"].dtype == torch.uint8
    snapshot = sharded.__reduce__()[2]["shards"]
    assert torch.equal(torch.cat([part["qpos"] for part in snapshot]), state["qpos"])


@pytest.mark.parametrize("call", ["step", "reset", "get_state"])
def test_a_worker_that_dies_is_one_line_not_a_hang(sharded, call):
    """Whether the caller was stepping or sending a command (whose pipe then breaks: a
    BrokenPipeError, which the command line took for a closed stdout and ended in silence)."""
    sharded.reset(seed=0)
    worker = sharded._workers[0].process
    os.kill(worker.pid, signal.SIGKILL)
    worker.join()
    calls = {"step": lambda: sharded.step(torch.zeros(128, 1)),
             "reset": lambda: sharded.reset(seed=1), "get_state": sharded.get_state}
    with pytest.raises(LabError, match="env shard 1's worker process ended"):
        calls[call]()


ORPHANED = """
import sys, time
from labcli.envs.shards import ShardedVecEnv
from labcli.plugins import registry
spec = registry.get_task("cartpole")
env = ShardedVecEnv(spec, spec.config_class(num_envs=128), shards=2)
print(env._workers[0].process.pid, flush=True)
time.sleep(600)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_end_when_their_parent_is_killed():
    """Killed without a chance to close its shards (SIGKILL, the OOM killer), a process leaves
    no worker behind to burn the cores."""
    parent = subprocess.Popen([sys.executable, "-c", ORPHANED], stdout=subprocess.PIPE, text=True)
    worker = int(parent.stdout.readline())
    parent.kill()
    parent.wait()
    deadline = time.monotonic() + 5
    while os.path.exists(f"/proc/{worker}") and _state(worker) != "Z":
        assert time.monotonic() < deadline, "the worker outlived its parent by 5 s"
        time.sleep(0.05)


def _state(pid: int) -> str:
    try:
        return open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"


class FailsInAWorker(Cartpole):
    """Cartpole whose third step fails in every shard but the first (a worker's)."""

    steps = 0

    def after_step(self) -> None:
        self.steps += 1
        if self.steps == 3 and self.rng.blocks[0] > 0:
            raise ValueError("the third step failed")


def test_a_step_that_fails_in_a_worker_is_one_line_and_the_next_step_goes_on():
    spec = dataclasses.replace(registry.get_task("cartpole"), task=FailsInAWorker)
    env = ShardedVecEnv(spec, spec.config_class(num_envs=128), seed=0, shards=2)
    try:
        env.reset(seed=0)
        for _ in range(2):
            env.step(torch.zeros(128, 1))
        with pytest.raises(LabError, match="^env shard 1 \\(a worker process\\): the third"):
            env.step(torch.zeros(128, 1))
        obs, *_ = env.step(torch.zeros(128, 1))  # the worker answers this step, not the last
        assert torch.equal(env.get_state()["episode_length"], torch.full((128,), 4))
        assert torch.isfinite(obs).all()
    finally:
        env.close()


@pytest.mark.parametrize("total, block", [(64, 4), (100, 6)])  # blocks of 6 and 7 envs
def test_envs_draw_the_same_numbers_in_shards_and_in_one_batch(total, block):
    half = total // 2
    whole, second = EnvRandom(total, "cpu"), EnvRandom(half, "cpu", first=half, total=total)
    whole.manual_seed(7)
    second.manual_seed(7)
    assert torch.equal(whole.rand(3)[half:], second.rand(3))
    # Blocks with no env in the reset mask neither draw nor advance.
    mask = torch.zeros(half, dtype=torch.bool)
    mask[0] = True  # in the shard's first block
    with second.only_for(mask):
        partial = second.uniform_(torch.full((half, 3), -1.0))
    assert (partial[block:] == -1).all() and (partial[:block] >= 0).all()
    assert torch.equal(second.rand(3)[block:], whole.rand(3)[half + block:])
    normal = whole.normal_(torch.empty(total, 2))
    assert torch.equal(second.normal_(torch.empty(half, 2))[block:], normal[half + block:])
    with pytest.raises(ValueError, match="not whole blocks"):
        EnvRandom(30, "cpu", first=1, total=64)


def test_one_block_draws_each_tensor_whole_and_resumes_from_a_state_of_many():
    """A GPU env's generator (one block): a draw is one draw of the whole tensor; a state saved
    per block (a GPU run of a lab before one generator) resumes from its first block's."""
    one, blocks = EnvRandom(64, "cpu", blocks=1), EnvRandom(64, "cpu")
    one.manual_seed(7)
    blocks.manual_seed(7)
    assert len(one.generators) == 1 and len(blocks.generators) == 16
    first = torch.Generator().set_state(blocks.generators[0].get_state())
    assert torch.equal(one.rand(3), torch.empty(64, 3).uniform_(generator=first))
    saved = blocks.get_state()
    one.check_state(saved)
    one.set_state(saved)
    assert torch.equal(one.get_state(), saved[:1])
    assert torch.equal(one.normal_(torch.empty(64, 2)),
                       torch.empty(64, 2).normal_(generator=blocks.generators[0]))
    for bad in (saved[:0], saved[0]):  # no row; a row not in a stack
        with pytest.raises(ValueError, match="not a row for each of 1 blocks"):
            one.check_state(bad)
    with pytest.raises(ValueError, match="not a row for each of 16 blocks"):
        blocks.check_state(one.get_state())


def test_only_for_draws_for_the_blocks_in_its_mask_and_says_whether_there_are_any():
    rng = EnvRandom(8, "cpu")  # blocks of one env
    rng.manual_seed(1)
    with rng.only_for(torch.zeros(8, dtype=torch.bool)) as some:
        assert not some
    mask = torch.zeros(8, dtype=torch.bool)
    mask[[2, 5]] = True
    before = rng.get_state()
    with rng.only_for(mask) as some:
        assert some
        drawn = rng.uniform_(torch.full((8, 1), -1.0))
        with rng.only_for(mask.roll(1)):  # inside another: the outer selection comes back
            pass
        again = rng.uniform_(torch.full((8, 1), -1.0))
    after = rng.get_state()
    assert [not torch.equal(a, b) for a, b in zip(before, after, strict=True)] == \
        [b in (2, 5) for b in range(8)]
    assert (drawn[mask] >= 0).all() and (drawn[~mask] == -1).all()
    assert (again[~mask] == -1).all()
    assert (rng.rand(1) >= 0).all()  # after it, every block draws


def test_the_shard_count_follows_threads_cores_and_envs(monkeypatch):
    monkeypatch.setattr(shards_module, "cores", lambda: 16)
    assert [shard_count(4096, t) for t in (1, 2, 3, 4, 7, 8, 12, 16, 32)] == \
        [1, 2, 2, 4, 4, 8, 8, 16, 16]
    assert shard_count(4096, None) == 16
    assert [shard_count(n, 16) for n in (64, 128, 256, 1024)] == [1, 2, 4, 16]
    monkeypatch.setattr(shards_module, "cores", lambda: 2)
    assert shard_count(4096, 16) == 2  # no more processes than cores
    monkeypatch.setattr(shards_module, "cores", lambda: 1)
    assert shard_count(4096, None) == 1
    with pytest.raises(LabError, match="do not make 3 shards"):
        build("cartpole", 128, shards=3)


def test_make_env_shards_the_cpu_backend_on_two_threads_or_more(monkeypatch):
    monkeypatch.setattr(shards_module, "cores", lambda: 4)
    spec = registry.get_task("cartpole")
    for threads in (4, 2):
        env = make_env(spec, spec.config_class(num_envs=256, threads=threads), seed=0)
        try:
            assert isinstance(env, ShardedVecEnv) and env.threads == threads
        finally:
            env.close()
    for num_envs, threads in ((256, 1), (64, 2)):  # one thread; too few envs for two shards
        one = make_env(spec, spec.config_class(num_envs=num_envs, threads=threads), seed=0)
        assert isinstance(one, LabVecEnv)
        one.close()
