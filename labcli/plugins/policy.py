"""What a framework's `load_policy` returns: the deterministic policy with its observation
normalizer inside, so that what is played and exported is exactly what was trained."""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from torch import nn

from labcli import files
from labcli.errors import LabError, first_line

# A checkpoint larger than this holds no policy-sized network.
CHECKPOINT_LIMIT = 2 << 30
# Nor a network with more parameters: a damaged size (10^7 units a layer) must be refused before
# the allocation that would exhaust memory.
MAX_PARAMETERS = 200_000_000


class ObsNormalizer(nn.Module):
    """(obs - mean) / sqrt(var + eps), clipped: the frozen form of a running normalizer."""

    def __init__(self, mean: torch.Tensor, var: torch.Tensor, eps: float, clip: float | None):
        super().__init__()
        self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float32).clone())
        self.register_buffer("std", torch.sqrt(torch.as_tensor(var, dtype=torch.float32) + eps))
        self.clip = clip

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        out = (obs - self.mean) / self.std
        return out if self.clip is None else out.clamp(-self.clip, self.clip)


class Policy(nn.Module):
    """Observation → deterministic action, clipped to ±`clip` as the env clips it, with the
    observation normalizer inside, so that what is played and exported is exactly what was
    trained. lab sets `clip` to the env's `clip_actions` when it loads a checkpoint: the bound
    is the task's, not the library's."""

    def __init__(self, actor: nn.Module, normalizer: nn.Module | None = None, clip: float = 1.0):
        super().__init__()
        self.normalizer = normalizer if normalizer is not None else nn.Identity()
        self.actor = actor
        self.clip = clip

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.actor(self.normalizer(obs)).clamp(-self.clip, self.clip)


def one_torch_thread(device: str) -> contextlib.AbstractContextManager[None]:
    """On CPU, step the env and run the policy on one torch thread. Their ops are small: more
    threads only add synchronization, and their spinning fights MuJoCo's threads for the cores
    (measured on 2 cores: 6 RSL-RL cartpole iterations took 28 s with 2 threads, 2 s with 1;
    an skrl backward pass 44 ms against 1 ms). A learner's update takes `TrainContext`'s
    `update_threads` (see `torch_threads`)."""
    return torch_threads(device, 1)


@contextlib.contextmanager
def torch_threads(device: str, threads: int) -> Iterator[None]:
    """On CPU, torch's intra-op threads inside the block are `threads`; on a GPU, unchanged."""
    if torch.device(device).type != "cpu":
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def read_torch_file(path: Path, device: str = "cpu", what: str = "checkpoint") -> Any:
    """What `torch.save` wrote at `path`, read as data: a regular file of bounded size, loaded
    with `weights_only=True` (tensors and plain containers; a pickled object is refused, never
    run). Anything else is a LabError naming the file."""
    try:
        data = files.read_bytes(path, CHECKPOINT_LIMIT)
        return torch.load(io.BytesIO(data), map_location=device, weights_only=True)
    except files.Unreadable as exc:
        raise LabError(f"{what} {path} {exc}", "pick another checkpoint") from None
    except Exception as exc:  # torch.load of arbitrary bytes fails in many ways (struct.error,
        # EOFError, UnpicklingError...); with weights_only nothing else can happen: all mean "not
        # a torch file"
        raise LabError(f"{what} {path} is not a readable torch file: {type(exc).__name__}: "
                       f"{first_line(exc)}", "pick another checkpoint") from None


def check_mlp(checkpoint: Path, inputs: int, hidden: Any, outputs: int) -> list[int]:
    """The hidden layer sizes a checkpoint describes, checked before anything is allocated:
    positive integers, and a network of at most `MAX_PARAMETERS` parameters."""
    if not isinstance(hidden, list) or not all(
            isinstance(n, int) and not isinstance(n, bool) and n > 0 for n in hidden):
        raise LabError(f"checkpoint {checkpoint.name} describes hidden layers {hidden!r}, not a "
                       "list of positive sizes", "the checkpoint is damaged; pick another")
    sizes = [inputs, *hidden, outputs]
    parameters = sum(a * b + b for a, b in zip(sizes, sizes[1:], strict=False))
    if parameters > MAX_PARAMETERS:
        raise LabError(f"checkpoint {checkpoint.name} describes a network of {parameters:,} "
                       f"parameters (layers {sizes}), more than the {MAX_PARAMETERS:,} lab loads",
                       "the checkpoint is damaged; pick another")
    return hidden
