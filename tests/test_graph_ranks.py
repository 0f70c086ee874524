"""The graphed updates of RSL-RL and skrl on two GPUs, against each library's own data-parallel
update: on every rank the same parameters, learning rate and losses as the library's within
float tolerance over several updates, each rank with its own rollouts, and the ranks' agents
bitwise equal (their gradients and KL averaged inside the graph). On the CPU, the averaging
itself, over two gloo ranks, against the libraries' reductions."""

from __future__ import annotations

import os
import socket

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from labcli.plugins.update_graph import average_over_ranks, release_graphs


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _join(rank: int, port: int, backend: str) -> str:
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    device = "cpu"
    if backend == "nccl":
        device = f"cuda:{rank}"
        torch.cuda.set_device(device)
    dist.init_process_group(backend, rank=rank, world_size=2)
    return device


def _assert_ranks_equal(tensors: dict[str, torch.Tensor]) -> None:
    for name, tensor in tensors.items():
        gathered = [torch.empty_like(tensor) for _ in range(2)]
        dist.all_gather(gathered, tensor.contiguous())
        assert torch.equal(gathered[0], gathered[1]), name


# The averaging, on the CPU -------------------------------------------------------------------
def _average_rank(rank: int, port: int) -> None:
    from rsl_rl.utils.utils import reduce_gradients_in_buckets

    _join(rank, port, "gloo")
    torch.manual_seed(rank)
    grads = [torch.randn(3, 4), torch.randn(7), torch.randn(())]
    library = [g.clone() for g in grads]
    reduce_gradients_in_buckets([_Param(g) for g in library], 2, 1.0)
    average_over_ranks(grads)
    for mine, theirs in zip(grads, library, strict=True):
        assert torch.equal(mine, theirs)
    _assert_ranks_equal({str(i): g for i, g in enumerate(grads)})
    dist.destroy_process_group()


class _Param:
    """What RSL-RL's reduction reads of a parameter: its gradient."""

    def __init__(self, grad: torch.Tensor):
        self.grad = grad


def test_gradients_are_averaged_over_the_ranks_as_rsl_rl_averages_them():
    mp.start_processes(_average_rank, args=(_free_port(),), nprocs=2, start_method="spawn")


# The graphed updates, on two GPUs ------------------------------------------------------------
def _rsl_rl_rank(rank: int, port: int) -> None:
    from test_rsl_rl_graph import algorithms, assert_same, rollout_and_update

    device = _join(rank, port, "nccl")
    eager, ours = algorithms(device, multi_gpu_cfg={"global_rank": rank, "local_rank": rank,
                                                    "world_size": 2})
    assert ours.graphed
    learning_rates = set()
    for iteration in range(4):
        data = 10 * rank + iteration  # each rank its own rollouts
        expected = rollout_and_update(eager, data)
        got = rollout_and_update(ours, data)
        assert got == pytest.approx(expected, rel=1e-4, abs=1e-6)
        assert_same(eager, ours, exact=False)
        learning_rates.add(ours.learning_rate)
    assert len(learning_rates) > 1, "the adaptive learning rate never moved: nothing compared"
    _assert_ranks_equal({f"{module}.{name}": value for module in ("actor", "critic")
                         for name, value in getattr(ours, module).state_dict().items()})
    release_graphs()
    dist.destroy_process_group()


def _skrl_rank(rank: int, port: int) -> None:
    from lab_skrl.ppo import RankedScaler, join_ranks
    from test_skrl_graph import agents, assert_same, learning_rate, rollout_and_update

    device = _join(rank, port, "nccl")
    join_ranks(rank, rank, 2)
    eager, ours = agents(device, observation_preprocessor=RankedScaler,
                         value_preprocessor=RankedScaler)
    assert ours.graphed
    learning_rates = set()
    for iteration in range(4):
        data = 10 * rank + iteration
        expected = rollout_and_update(eager, data)
        got = rollout_and_update(ours, data)
        assert got == pytest.approx(expected, rel=1e-4, abs=1e-6)
        assert_same(eager, ours, exact=False)
        learning_rates.add(learning_rate(ours))
    assert len(learning_rates) > 1, "the adaptive learning rate never moved: nothing compared"
    _assert_ranks_equal({f"{name}.{key}": value
                         for name, module in ours.checkpoint_modules.items() if name != "optimizer"
                         for key, value in module.state_dict().items()
                         if isinstance(value, torch.Tensor)})
    release_graphs()
    dist.destroy_process_group()


@pytest.mark.gpu
@pytest.mark.skipif(torch.cuda.device_count() < 2, reason="needs two CUDA GPUs")
@pytest.mark.parametrize("rank_fn", [_rsl_rl_rank, _skrl_rank], ids=["rsl_rl", "skrl"])
def test_the_graphed_update_on_two_gpus_is_the_librarys(rank_fn):
    mp.start_processes(rank_fn, args=(_free_port(),), nprocs=2, start_method="spawn")
