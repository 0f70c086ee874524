"""`lab train --nproc N`: torchrun's launcher (torch.distributed.elastic's agent), run inside
`lab` rather than beside it. It starts N ranks of the same `lab train` command on this host
(`--nnodes` and a rendezvous endpoint join several hosts, as torchrun's flags do), watches them,
and ends them all when one fails. What it adds to `torchrun -m labcli train ...` is one line
instead of torchrun's report when a rank dies, and the exit code of the rank that failed."""

from __future__ import annotations

import dataclasses
import logging
import os
import sys
import threading
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from rich.console import Console

from labcli import endpoints
from labcli.errors import LabError, first_line
from labcli.runs import ranks

# The options that only the launcher reads: the ranks run the command without them.
LAUNCH_OPTIONS = ("--nproc", "--nnodes", "--rdzv-endpoint", "--rdzv-id")
# A stop must reach every rank's checkpoint: the agent waits this long after passing a signal
# on before it kills the ranks.
SHUTDOWN_TIMEOUT_S = 300
# The c10d rendezvous, under a name of lab's (`_register_rendezvous`).
RENDEZVOUS = "lab-c10d"
PARENT_LOGGER = "torch.distributed.elastic"
# How long a host tries to reach the rendezvous's store (another host may not have started it
# yet), and how long more it waits for the store to answer once connected.
STORE_TIMEOUT_S = 60
ANSWER_TIMEOUT_S = 15


@dataclass(frozen=True)
class Launch:
    nproc: int
    nnodes: str = "1"  # "N", or "MIN:MAX" for an elastic number of hosts
    rdzv_endpoint: str | None = None  # host:port of the rendezvous, on several hosts
    rdzv_id: str | None = None  # the same on every host of one run

    def nodes(self) -> tuple[int, int]:
        try:
            low, _, high = self.nnodes.partition(":")
            nodes = int(low), int(high or low)
        except ValueError:
            nodes = (0, 0)
        if not 1 <= nodes[0] <= nodes[1]:
            raise LabError(f"--nnodes '{self.nnodes}' is not a number of hosts",
                           "pass e.g. --nnodes 2, or --nnodes 1:4")
        return nodes

    def check(self) -> int:
        """The most ranks the run may have; a LabError for flags that cannot launch."""
        if self.nproc < 1:
            raise LabError(f"--nproc must be a positive integer, got {self.nproc}")
        low, high = self.nodes()
        if high > 1 and not (self.rdzv_endpoint and self.rdzv_id):
            raise LabError(f"--nnodes {self.nnodes} without --rdzv-endpoint and --rdzv-id",
                           "give every host the same --rdzv-endpoint HOST:PORT and --rdzv-id")
        if self.rdzv_id is not None and high == 1:
            raise LabError("--rdzv-id names a run of several hosts, and this one has one",
                           "leave it out, or add --nnodes N --rdzv-endpoint HOST:PORT")
        if self.rdzv_endpoint is not None:
            self.endpoint()
        return self.nproc * high

    def endpoint(self) -> tuple[str, int]:
        """--rdzv-endpoint as a host this machine can resolve and a port."""
        return endpoints.parse(self.rdzv_endpoint or "", "--rdzv-endpoint", "node0:29400")


def rank_argv(argv: Sequence[str]) -> list[str]:
    """`argv` without the launcher's options (`--nproc 2` or `--nproc=2`)."""
    out, skip = [], False
    for arg in argv:
        if skip:
            skip = False
        elif arg in LAUNCH_OPTIONS:
            skip = True
        elif not arg.startswith(tuple(f"{option}=" for option in LAUNCH_OPTIONS)):
            out.append(arg)
    return out


def launch(launch: Launch, argv: Sequence[str], console: Console) -> int:
    """Run `lab <argv>` on `launch.nproc` ranks per host and return the exit code: 0, that of
    the rank that failed first, or 128 + the signal that stopped the launcher."""
    from torch.distributed.elastic.multiprocessing.api import SignalException
    from torch.distributed.elastic.multiprocessing.errors import ChildFailedError
    from torch.distributed.elastic.rendezvous.api import RendezvousError
    from torch.distributed.launcher.api import LaunchConfig, elastic_launch

    low, high = launch.nodes()
    one_host = high == 1 and launch.rdzv_endpoint is None
    # torch < 2.13 has no such setting: its agent waits 30 s.
    later = ({"shutdown_timeout": SHUTDOWN_TIMEOUT_S}
             if "shutdown_timeout" in {f.name for f in dataclasses.fields(LaunchConfig)} else {})
    _register_rendezvous()
    config = LaunchConfig(
        min_nodes=low, max_nodes=high, nproc_per_node=launch.nproc,
        run_id=launch.rdzv_id or uuid.uuid4().hex, rdzv_backend=RENDEZVOUS,
        # torchrun's --standalone: a rendezvous on a free local port.
        rdzv_endpoint="localhost:0" if one_host else launch.rdzv_endpoint or "",
        rdzv_configs={"read_timeout": STORE_TIMEOUT_S}, max_restarts=0, **later)
    _quiet_elastic_agent()
    launched = os.environ.get(ranks.LAUNCHED)
    os.environ[ranks.LAUNCHED] = "1"  # inherited by the ranks
    try:
        elastic_launch(config, sys.executable)("-m", "labcli", *rank_argv(argv))
    except RendezvousError as exc:
        raise LabError(f"--rdzv-endpoint {launch.rdzv_endpoint}: {first_line(exc)}",
                       "start lab train with the same --rdzv-endpoint on the host that has "
                       "it, and open its port to the others") from None
    except ChildFailedError as exc:
        rank, failure = exc.get_first_failure()
        if failure.exitcode == ranks.PEER_LOST_EXIT:  # a consequence: the cause is another's
            causes = [(r, f) for r, f in exc.failures.items()
                      if f.exitcode != ranks.PEER_LOST_EXIT]
            if not causes:  # the rank that ended it is another host's, whose launcher says so
                console.print("error: a rank on another host stopped answering; the ranks here "
                              "were stopped (the run keeps its last checkpoint: resume it with "
                              "--checkpoint latest and as many ranks)", highlight=False,
                              soft_wrap=True)
                return 1
            rank, failure = min(causes, key=lambda cause: cause[1].timestamp)
        if failure.exitcode > 0:  # it said why itself, in its own line
            return failure.exitcode
        console.print(f"error: rank {rank} was ended by {failure.signal_name()}; the other "
                      "ranks were stopped (the run keeps its last checkpoint: resume it with "
                      "--checkpoint latest)", highlight=False, soft_wrap=True)
        return 1
    except SignalException as exc:  # passed on to the ranks, which checkpointed and stopped
        return 128 + int(exc.sigval)
    finally:
        if launched is None:
            os.environ.pop(ranks.LAUNCHED, None)
    return 0



def _rendezvous_handler(params: Any) -> Any:
    """torchrun's c10d rendezvous, whose store is reached within a stated time: its own client
    waits forever on a listener that accepts and never answers (a port another program holds),
    and is given STORE_TIMEOUT_S + ANSWER_TIMEOUT_S here, in a thread of its own."""
    from torch.distributed.elastic.rendezvous.api import RendezvousConnectionError
    from torch.distributed.elastic.rendezvous.c10d_rendezvous_backend import create_backend
    from torch.distributed.elastic.rendezvous.dynamic_rendezvous import create_handler

    made: list[Any] = []
    failed: list[BaseException] = []

    def connect() -> None:
        try:
            made.extend(create_backend(params))
        except BaseException as exc:  # re-raised in the caller's thread
            failed.append(exc)

    thread = threading.Thread(target=connect, name="lab-rendezvous", daemon=True)
    thread.start()
    thread.join(STORE_TIMEOUT_S + ANSWER_TIMEOUT_S)
    if failed:
        raise failed[0]
    if not made:
        raise RendezvousConnectionError(f"no rendezvous store answered at {params.endpoint} "
                                        f"within {STORE_TIMEOUT_S + ANSWER_TIMEOUT_S} s")
    backend, store = made
    params.backend = backend.name  # c10d's rendezvous, which checks that it was asked for
    return create_handler(store, backend, params)


def _quiet_elastic_agent() -> None:
    """The agent logs every worker it starts and stops, and a Ctrl-C as a "death signal"; a
    failure is said in one line by lab. torch's elastic modules each set their own logger's
    level (LOGLEVEL, else WARNING), so the parent logger's level alone does not reach them."""
    loggers = logging.root.manager.loggerDict
    for name in [PARENT_LOGGER, *(n for n in loggers if n.startswith(PARENT_LOGGER + "."))]:
        logging.getLogger(name).setLevel(logging.CRITICAL)


def _register_rendezvous() -> None:
    from torch.distributed.elastic.rendezvous.api import rendezvous_handler_registry

    rendezvous_handler_registry.register(RENDEZVOUS, _rendezvous_handler)
