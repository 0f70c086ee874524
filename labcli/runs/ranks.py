"""Where this process stands in a data-parallel run, from torchrun's variables; no torch here:
`lab train` reads it before its first line (labcli/runs/distributed.py has the collectives)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

from labcli.errors import LabError

TORCHRUN_VARIABLES = ("RANK", "LOCAL_RANK", "WORLD_SIZE")
# Set by `lab train --nproc` for its ranks: a rank that lost another exits with
# `PEER_LOST_EXIT` and no line of its own, and the launcher, which sees every rank's end, says
# which rank ended the run, in one line.
LAUNCHED = "LAB_LAUNCHED"
PEER_LOST_EXIT = 3


@dataclass(frozen=True)
class Ranks:
    rank: int = 0
    local_rank: int = 0
    world_size: int = 1
    local_world_size: int = 1  # the ranks on this host, which share its cores

    @property
    def writer(self) -> bool:
        """Rank 0 owns the run dir, the progress bar and TensorBoard; the others write nothing."""
        return self.rank == 0

    @property
    def active(self) -> bool:
        return self.world_size > 1


SINGLE = Ranks()


def from_environment(environ: Mapping[str, str] = os.environ) -> Ranks:
    """This process's place among the ranks, from torchrun's variables; one rank without them."""
    if "WORLD_SIZE" not in environ:
        return SINGLE
    try:
        rank, local_rank, world_size = (int(environ.get(name, "0"))
                                        for name in TORCHRUN_VARIABLES)
    except ValueError:
        shown = ", ".join(f"{name}={environ.get(name)!r}" for name in TORCHRUN_VARIABLES)
        raise LabError(f"torchrun's variables are not integers: {shown}",
                       "start ranks with torchrun or lab train --nproc") from None
    if not 0 <= rank < world_size or not 0 <= local_rank < world_size:
        raise LabError(f"RANK={rank}, LOCAL_RANK={local_rank} with WORLD_SIZE={world_size}",
                       "start ranks with torchrun or lab train --nproc")
    local_world_size = environ.get("LOCAL_WORLD_SIZE", str(world_size))
    if not local_world_size.isdigit() or not 0 < int(local_world_size) <= world_size:
        raise LabError(f"LOCAL_WORLD_SIZE={local_world_size!r} with WORLD_SIZE={world_size}",
                       "start ranks with torchrun or lab train --nproc")
    return Ranks(rank, local_rank, world_size, int(local_world_size))
