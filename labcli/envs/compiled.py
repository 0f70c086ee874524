"""The cpu backend's env step traced once and compiled with TorchInductor (`env.compile`).

On the CPU a step's torch code is some fifty to a hundred small ops, each of which costs its
dispatch (1.5-4 µs) more than its arithmetic over a shard's few dozen envs; on many cores that
code, run in every env shard after the physics, is what keeps the step from MuJoCo's own speed
(docs/benchmarks.md). Traced once and compiled, the same ops are a few fused C++ loops. As for a
GPU's CUDA graph (`cuda_graph.py`), the step must then be free of host reads and keep writing into
the tensors it was traced with, which the task API already asks of every task.

The trace (`make_fx` on real tensors) runs the step for real once. The tensors the step reads
from its objects (the state, the task's buffers) become the compiled graph's inputs as views of
their storages, so that the compiled step reads and writes those same tensors in place. Its
random draws (`EnvRandom`'s, per block of envs) are made before the compiled code runs, each
into a tensor of its own that the code copies from where the step drew: a compiled step reads
no mask on the host, so every block draws on every step, whatever the step does.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

import torch

from labcli.envs.random import EnvRandom
from labcli.errors import LabError, first_line

# The flag a user sets to step eagerly instead (a TaskConfig field).
FLAG = "env.compile"


class CompiledStep:
    """`fn(*inputs)` (which writes its results into tensors and returns nothing): traced on its
    first call, which runs it, and compiled; later calls run the compiled code on the inputs
    given, which must be shaped as the first call's. `rng`'s draws are made before the compiled
    code runs (see the module's text)."""

    def __init__(self, fn: Callable[..., object], what: str, rng: EnvRandom):
        self._fn = fn
        self._what = what
        self._rng = rng
        self._compiled: Callable[..., object] | None = None
        self._bases: list[torch.Tensor] = []
        # Each draw of the step: the tensor it is made into ahead, and how to make it.
        self._draws: list[tuple[torch.Tensor, Callable[[torch.Tensor], torch.Tensor]]] = []

    @property
    def ready(self) -> bool:
        """Whether the step is compiled (its first call was made)."""
        return self._compiled is not None

    def __call__(self, *inputs: torch.Tensor) -> None:
        if self._compiled is None:
            with self._rng.deferred(self._draw_ahead):
                self._compiled, self._bases = _compile(self._fn, inputs, self._what)
            return
        for ahead, fill in self._draws:
            fill(ahead)
        self._compiled(*inputs, *self._bases)

    def _draw_ahead(self, out: torch.Tensor, fill: Callable[[torch.Tensor], torch.Tensor]
                    ) -> torch.Tensor:
        """A draw met in the trace: made now (the trace runs the step), into a tensor that later
        calls fill before the compiled code; the step copies it where it drew."""
        from torch.fx.experimental.proxy_tensor import disable_proxy_modes_tracing

        with disable_proxy_modes_tracing():
            ahead = fill(torch.empty(out.shape, dtype=out.dtype, device=out.device))
        self._draws.append((ahead, fill))
        return out.copy_(ahead)


@contextmanager
def compiling_notice() -> Iterator[None]:
    """A line before an env's first compiled step and one after it: it compiles for seconds to
    minutes, often under a training run's progress bar. Written to `sys.stderr` as it is then,
    which a live bar redirects to print above itself (a rich Console would write past it to the
    terminal, and a spinner would be a second live display)."""
    from torch._inductor.runtime.cache_dir_utils import cache_dir

    print(f"compiling the env step ({FLAG}=true; cached in {cache_dir()})", file=sys.stderr,
          flush=True)
    start = time.perf_counter()
    yield
    print(f"env step compiled in {time.perf_counter() - start:.0f} s", file=sys.stderr,
          flush=True)


def _compile(fn: Callable[..., object], inputs: Sequence[torch.Tensor], what: str):
    # Imported here: inductor takes seconds to import, and only this option needs it.
    import torch._inductor
    from torch.fx.experimental.proxy_tensor import make_fx

    def traced(*args: torch.Tensor) -> None:
        fn(*args)

    with torch.no_grad():
        try:
            graph = make_fx(traced, tracing_mode="real")(*inputs)
        except RuntimeError as exc:
            raise LabError(
                f"{what} could not be traced to compile it ({first_line(exc)}); a step that "
                "reads a tensor on the host (.item(), .tolist(), a Python `if` on a tensor) "
                "cannot be", f"keep such code out of the task's step, or --set {FLAG}=false "
                "to step eagerly") from exc
        bases = _lift_tensors(graph, inputs)
        try:
            # compile_threads: each env shard compiles in its own process already, and inductor
            # would otherwise start a pool of compile workers in each. fallback_random: a draw
            # not through EnvRandom stays torch's own. size_asserts: every call's inputs are
            # shaped and strided as the first's, the env's own tensors or new ones made alike
            # (~0.4 µs a check, 26 checks a cartpole step). cpp.threads: a shard's step is one
            # thread's work beside the others', and inductor's cache key holds the thread
            # count, so the caller's code (its torch threads: the machine's) would otherwise be
            # compiled again in every worker (one thread each). vec_isa_ok: AVX2 and AVX-512
            # are used as the CPU's flags say, without inductor's probe of each, which builds a
            # library and loads it in a child Python under a lock all shards share (on torch
            # 2.11 that child imports torch: seconds a probe, a shard after another); its
            # probes of AVX-512 extensions and AMX run whatever this says.
            with torch._inductor.config.patch({"fallback_random": True, "compile_threads": 1,
                                               "size_asserts": False, "cpp.threads": 1,
                                               "cpp.vec_isa_ok": True}):
                compiled = torch._inductor.compile(graph, _static_fakes([*inputs, *bases]))
        except Exception as exc:  # a missing C++ compiler, an op inductor cannot lower
            raise LabError(f"{what} could not be compiled: {first_line(exc)}",
                           f"install a C++ compiler (g++ or clang), or --set {FLAG}=false "
                           "to step eagerly") from exc
    return compiled, bases


def _lift_tensors(graph: torch.fx.GraphModule, inputs: Sequence[torch.Tensor]
                  ) -> list[torch.Tensor]:
    """Turn the tensors the trace found in objects (its constants) into inputs: one flat tensor
    per storage, over the span the step touches, of which each constant is a strided view. A
    compiled graph would otherwise own copies of its constants, and views of one storage (the
    state and its columns) would no longer alias. The flat tensors are returned, to be passed
    after `inputs` on every call."""
    nodes = [node for node in graph.graph.nodes if node.op == "get_attr"
             and isinstance(getattr(graph, node.target), torch.Tensor)]
    # Per storage (by address): the span of it the step touches, its dtype, the storage.
    spans: dict[int, tuple[int, int, torch.dtype, torch.UntypedStorage]] = {}
    for node in nodes:
        tensor = getattr(graph, node.target)
        start, stop = _span(tensor)
        storage = tensor.untyped_storage()
        low, high, dtype, _ = spans.get(storage.data_ptr(),
                                        (start, stop, tensor.dtype, storage))
        if dtype != tensor.dtype:
            raise LabError("the env step reads one storage as two dtypes: it cannot be "
                           "compiled", f"--set {FLAG}=false to step eagerly")
        spans[storage.data_ptr()] = (min(low, start), max(high, stop), dtype, storage)
    if any(t.untyped_storage().data_ptr() in spans for t in inputs):
        raise LabError("the env step's inputs share memory with the tensors it reads: it "
                       "cannot be compiled", f"--set {FLAG}=false to step eagerly")
    bases = {key: torch.empty(0, dtype=dtype).set_(storage, low, (high - low,), (1,))
             for key, (low, high, dtype, storage) in spans.items()}
    placeholders = [node for node in graph.graph.nodes if node.op == "placeholder"]
    first_op = placeholders[-1].next if placeholders else next(iter(graph.graph.nodes))
    with graph.graph.inserting_before(first_op):
        base_nodes = {key: graph.graph.placeholder(f"storage_{i}")
                      for i, key in enumerate(bases)}
    for node in nodes:
        tensor = getattr(graph, node.target)
        key = tensor.untyped_storage().data_ptr()
        with graph.graph.inserting_before(node):
            view = graph.graph.call_function(
                torch.ops.aten.as_strided.default,
                (base_nodes[key], list(tensor.shape), list(tensor.stride()),
                 tensor.storage_offset() - spans[key][0]))
        node.replace_all_uses_with(view)
        graph.graph.erase_node(node)
    for name in {node.target for node in nodes}:
        delattr(graph, name)
    graph.graph.lint()
    graph.recompile()
    return list(bases.values())


def _span(tensor: torch.Tensor) -> tuple[int, int]:
    """The elements of its storage that `tensor` covers: `[first, last + 1)`."""
    start = tensor.storage_offset()
    if tensor.numel() == 0:
        return start, start
    last = start + sum((size - 1) * stride for size, stride in zip(tensor.shape,
                                                                     tensor.stride(),
                                                                     strict=True))
    return start, last + 1


def _static_fakes(tensors: Sequence[torch.Tensor]) -> list[torch.Tensor]:
    """`tensors` as fake tensors of fixed shapes with a shape environment: inductor caches the
    compiled code on disk only then (the env's other shards, the next run, load it)."""
    from torch._subclasses.fake_tensor import FakeTensorMode
    from torch.fx.experimental.symbolic_shapes import ShapeEnv

    mode = FakeTensorMode(shape_env=ShapeEnv(), static_shapes=True)
    return [mode.from_tensor(tensor, static_shapes=True) for tensor in tensors]
