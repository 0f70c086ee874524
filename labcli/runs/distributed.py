"""Data-parallel training, the side of one rank. `torchrun` (or `lab train --nproc`, which runs
torchrun's launcher in-process: labcli/runs/launcher.py) starts one process per rank with RANK,
LOCAL_RANK and WORLD_SIZE set. Each steps its own envs, seeded apart, and trains the same agent,
whose library averages the gradients over the ranks (RSL-RL's and skrl's own code). lab sets up
the process group before the library is imported: gloo on the CPU, NCCL on GPUs (both libraries
would ask for NCCL, which has no CPU). Rank 0 alone writes the run dir; lab itself adds two tiny
collectives per iteration (the episode figures' totals, summed, and the stop request, agreed
on) and a gather at checkpoints (every rank's episodes in flight)."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import threading
import time
import traceback
from collections.abc import Iterator
from datetime import timedelta
from typing import Any

import torch
import torch.distributed as dist

from labcli.errors import LabError, first_line
from labcli.plugins.update_graph import release_graphs
from labcli.runs.ranks import TORCHRUN_VARIABLES, Ranks

# Long enough for a rank that builds its envs slowly (MuJoCo Warp compiles its kernels for a
# minute on first use) or waits while rank 0 writes a checkpoint; a rank that died fails the
# others at once (its sockets close), so this only bounds a rank that hangs.
TIMEOUT = timedelta(minutes=10)
# How often a rank checks that its launcher lives.
ORPHAN_CHECK_S = 0.5


class RankLost(LabError):
    """Another rank stopped answering (it died, or was killed): this one stops too. Under
    `lab train --nproc` the launcher says it (`ranks.LAUNCHED`)."""

    exit_code = 1
    said_by_launcher = True


def device_of(ranks: Ranks, device: str) -> str:
    """On GPUs each rank takes `cuda:<local rank>`; a device naming another GPU is refused."""
    dev = torch.device(device)
    if not ranks.active or dev.type != "cuda":
        return device
    if dev.index is not None and dev.index != ranks.local_rank:
        raise LabError(f"--device {device} on local rank {ranks.local_rank}: each rank takes "
                       "the GPU of its local rank", "pass --device cuda")
    if ranks.local_rank >= torch.cuda.device_count():
        raise LabError(f"local rank {ranks.local_rank} has no GPU: {torch.cuda.device_count()} "
                       "are visible", "start at most one rank per GPU on each host")
    return f"cuda:{ranks.local_rank}"


@contextlib.contextmanager
def process_group(ranks: Ranks, device: str) -> Iterator[None]:
    """torch.distributed's default group for the ranks, for as long as training lasts."""
    if not ranks.active:
        yield
        return
    # torch.distributed.nn.functional binds `group.WORLD` as its functions' default argument
    # when it is imported; imported after the group exists (RSL-RL imports it, through
    # tensordict and torch.compiler), it kept the group alive past destroy_process_group, and
    # gloo's threads ran on into the interpreter's teardown, where a rank now and then aborted
    # ("terminate called without an active exception"). Imported first, it binds None.
    import torch.distributed.nn  # noqa: F401

    cuda = torch.device(device).type == "cuda"
    if cuda:
        torch.cuda.set_device(torch.device(device))
    try:
        dist.init_process_group("nccl" if cuda else "gloo", rank=ranks.rank,
                                world_size=ranks.world_size, timeout=TIMEOUT)
    except (RuntimeError, ValueError) as exc:
        raise RankLost(f"rank {ranks.rank}: the ranks did not meet: {first_line(exc)}",
                       "check that every rank runs, with the same MASTER_ADDR and MASTER_PORT"
                       ) from None
    _stop_when_orphaned()
    # The group is lab's: a library reading torchrun's variables would set up NCCL again
    # (skrl does, when imported); each is told the ranks through TrainContext instead.
    consumed = {name: os.environ.pop(name) for name in TORCHRUN_VARIABLES if name in os.environ}
    finished = False
    try:
        yield
        finished = True
    finally:
        os.environ.update(consumed)
        if finished:
            # No rank tears its group down while another may still use it: without this wait
            # rank 1 aborted at exit ("terminate called without an active exception") in 4 of 9
            # runs of tests/test_distributed.py and test_interrupt.py on a 2-core VM, 0 of 6 with.
            with contextlib.suppress(RuntimeError):
                # NCCL's barrier, told no device, warns that it guesses the current one.
                dist.barrier(device_ids=[torch.cuda.current_device()] if cuda else None)
        release_graphs()
        dist.destroy_process_group()


def _stop_when_orphaned() -> None:
    """SIGTERM to this rank once the launcher that started it is gone (killed without a
    chance to stop its ranks: SIGKILL, the OOM killer): the ranks stop after the iteration, as
    a scheduler's SIGTERM stops them, and the run keeps its checkpoint, instead of training on
    unwatched. Polled: a parent's death signal would also fire when the launcher's thread that
    started the rank ends."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(ORPHAN_CHECK_S)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="lab-launcher-watch", daemon=True).start()


def _flags(device: str, values: list[float]) -> torch.Tensor:
    # NCCL reduces device tensors only; gloo, host ones.
    return torch.tensor(values, dtype=torch.float64, device=device)


def agreed_stop(signum: int | None, device: str) -> int | None:
    """The signal any rank was stopped by (None while none was): all ranks stop after the same
    iteration, however many were asked (a rank leaving alone would leave the others waiting in
    the next update's collectives)."""
    flag = _flags(device, [float(signum or 0)])
    dist.all_reduce(flag, op=dist.ReduceOp.MAX)
    return int(flag.item()) or None


def summed(tensor: torch.Tensor, device: str) -> torch.Tensor:
    """The sum of `tensor` over the ranks, on every rank; `tensor` is left as it is."""
    total = tensor.to(device, copy=True)
    dist.all_reduce(total, op=dist.ReduceOp.SUM)
    return total


def gather_to_writer(ranks: Ranks, value: Any) -> list[Any] | None:
    """Every rank's `value` (small tensors and numbers), in rank order, on rank 0; None on the
    others."""
    gathered = [None] * ranks.world_size if ranks.writer else None
    dist.gather_object(value, gathered, dst=0)
    return gathered


def broadcast_from_writer(value: Any) -> Any:
    """Rank 0's `value` on every rank."""
    box = [value]
    dist.broadcast_object_list(box, src=0)
    return box[0]


def lost_peer(exc: BaseException) -> bool:
    """Whether `exc` came out of a collective: where the ranks stop answering (gloo: "Connection
    reset by peer"; NCCL: a watchdog's abort), the error rises from torch.distributed's calls."""
    if not isinstance(exc, RuntimeError) or not dist.is_initialized():
        return False
    return any(frame.f_code.co_filename.endswith(os.path.join("distributed", "distributed_c10d.py"))
               for frame, _ in traceback.walk_tb(exc.__traceback__))


def lost(ranks: Ranks, exc: BaseException, iteration: int | None = None) -> RankLost:
    # gloo's message: "[.../pair.cc:553] Connection closed by peer [addr]:port. This is..."
    detail = re.sub(r"^\[[^\]]*\]\s*", "", first_line(exc)).split(". ")[0]
    if iteration is None:
        return RankLost(f"rank {ranks.rank}: another rank stopped answering before training "
                        f"({detail})", "the first error above says why")
    return RankLost(f"rank {ranks.rank}: another rank stopped answering after iteration "
                    f"{iteration} ({detail})", "the run keeps its last checkpoint: resume it "
                    "with --checkpoint latest and as many ranks")
