"""GPU backend: MuJoCo Warp steps every env on CUDA. The decimation substeps replay as one CUDA
graph, resets as another, and `qpos`/`qvel`/`ctrl` are torch views of MuJoCo Warp's own arrays,
so a step costs no copies and no host round trip.

Kernels compile on first use (~1 min) into warp's kernel cache, `~/.cache/warp/<warp version>`,
or `$LAB_WARP_CACHE/<warp version>` where that variable is set; later starts load them (~5 s).
`LabVecEnv` captures its whole step with `torch.cuda.graph(..., capture_error_mode=
"thread_local")` (labcli/envs/cuda_graph.py): during a capture the sim records its kernels into
torch's graph.

Imported only by `make_sim("warp", ...)`: `lab` itself runs without warp installed.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

import mujoco
import mujoco_warp as mjw
import torch
import warp as wp
from rich.console import Console

from labcli.envs.sim import Sim

# Where compiled kernels are kept: this variable if set, else warp's default (~/.cache/warp/<ver>).
CACHE_ENV = "LAB_WARP_CACHE"
# A setup slower than this was a compile: say how long it took once it is done.
COMPILE_NOTICE_S = 5.0
RESET = "reset"  # key of the reset graph beside the step graphs, which are keyed by nstep


def init_warp() -> str:
    """Initialise warp once, quietly, with the kernel cache where `LAB_WARP_CACHE` says;
    returns the cache directory."""
    path = os.environ.get(CACHE_ENV)
    if path:
        wp.config.kernel_cache_dir = os.path.expanduser(path)
    if wp.config.log_level == wp.LOG_INFO:  # warp's default prints a line per loaded module
        wp.config.log_level = wp.LOG_WARNING
    wp.init()
    return str(wp.config.kernel_cache_dir)


def constraint_capacity(model: mujoco.MjModel, may_collide: bool) -> dict[str, int]:
    """`njmax`/`nconmax` for `put_data`: exact for a model without contacts (cartpole: two rows,
    its rail's limits), where MuJoCo Warp's defaults (njmax 64, nconmax 48) would cost up to a
    quarter of the throughput; MuJoCo Warp's own estimates where contacts or flexes may arise."""
    if may_collide or model.nflex:
        return {}
    eq_rows = {mujoco.mjtEq.mjEQ_CONNECT: 3, mujoco.mjtEq.mjEQ_WELD: 6,
               mujoco.mjtEq.mjEQ_JOINT: 1, mujoco.mjtEq.mjEQ_TENDON: 1}
    if any(int(t) not in eq_rows for t in model.eq_type):
        return {}
    ball = mujoco.mjtJoint.mjJNT_BALL
    rows = sum(eq_rows[int(t)] for t in model.eq_type)
    rows += int((model.dof_frictionloss > 0).sum()) + int((model.tendon_frictionloss > 0).sum())
    # A hinge, slide or tendon limit can hold a row at each end; a ball limit holds one.
    rows += sum(1 if t == ball else 2 for t, on in zip(model.jnt_type, model.jnt_limited,
                                                       strict=True) if on)
    rows += 2 * int(model.tendon_limited.sum())
    return {"njmax": max(rows, 1), "nconmax": 0}


@contextmanager
def compiling_notice(cache_dir: str) -> Iterator[None]:
    """A spinner while kernels compile or load (terminal only), and one line after a slow one.
    The ranks of a host compile the same kernels at once: its first rank alone says so."""
    # torchrun's variable, read here: the env layer knows nothing of ranks.
    console = Console(stderr=True, quiet=os.environ.get("LOCAL_RANK", "0") != "0")
    start = time.perf_counter()
    with console.status(f"compiling MuJoCo Warp kernels (first run only, cached in {cache_dir})"):
        yield
    seconds = time.perf_counter() - start
    if seconds > COMPILE_NOTICE_S:
        console.print(f"MuJoCo Warp kernels compiled in {seconds:.0f} s, cached in {cache_dir}",
                      highlight=False)


class WarpSim(Sim):
    def __init__(self, model: mujoco.MjModel, num_envs: int, device: str = "cuda",
                 nconmax: int | None = None, njmax: int | None = None,
                 per_env_fields: Sequence[str] = ()):
        self.model = model
        self.num_envs = num_envs
        cache_dir = init_warp()
        self.device = torch.device(device)
        if self.device.type == "cuda" and self.device.index is None:
            self.device = torch.device("cuda", torch.cuda.current_device())
        self._wp_device = wp.get_device(str(self.device))

        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        with wp.ScopedDevice(self._wp_device):
            # Fields that differ per env get a leading dimension of num_envs (MuJoCo Warp's
            # batched model fields), before any kernel is compiled or graph captured.
            self._m = mjw.put_model(model, batch_sizes={name: num_envs
                                                        for name in per_env_fields})
            may_collide = self._m.nxn_geom_pair_filtered.shape[0] > 0
            capacity = constraint_capacity(model, may_collide)
            # The task's sizes win (Isaac Lab's Newton configs give them per task): MuJoCo
            # Warp's own estimates are generous, and every slot costs throughput.
            capacity.update({k: v for k, v in (("nconmax", nconmax), ("njmax", njmax))
                             if v is not None})
            self._d = mjw.put_data(model, data, nworld=num_envs, **capacity)
            # Reset mask: a persistent array, so the captured reset graph keeps its address.
            self._mask = wp.zeros(num_envs, dtype=bool)
        self._mask_t = wp.to_torch(self._mask)
        # Live views of MuJoCo Warp's arrays (float32): never rebind them, graphs hold addresses.
        self.qpos = wp.to_torch(self._d.qpos)
        self.qvel = wp.to_torch(self._d.qvel)
        self.ctrl = wp.to_torch(self._d.ctrl)
        self.sensordata = wp.to_torch(self._d.sensordata)
        # Per env, the buffers that overflowed in a step (a bitmask MuJoCo Warp sets and never
        # clears): counted per buffer on the device and cleared after each step.
        overflow = getattr(self._d, "overflow", None)
        self._overflow = wp.to_torch(overflow) if overflow is not None else None
        kinds = [k for k in getattr(mjw, "OverflowType", []) if k.value and
                 k.value & (k.value - 1) == 0]
        self._overflow_names = [k.name for k in kinds]
        self._overflow_bits = torch.tensor([k.value for k in kinds], device=self.device)
        self._overflow_counts = torch.zeros(len(kinds), dtype=torch.float64, device=self.device)
        self._overflowed = torch.zeros(num_envs, dtype=torch.bool, device=self.device)
        # A buffer that overflowed lost contacts or constraints: that env's state is wrong. A
        # solver that ran out of iterations left its last iterate, as MuJoCo does on the CPU:
        # counted (sim/overflow/ITERATIONS), not an instability.
        self._corrupting = sum(k.value for k in kinds if "ITERATIONS" not in k.name)
        if hasattr(self._m.opt, "warn_overflow"):  # lab counts them: no line per step
            self._m.opt.warn_overflow = 0

        self._graphs: dict[object, wp.Graph | torch.cuda.CUDAGraph | None] = {}
        self._streams: dict[int, wp.Stream] = {}
        with compiling_notice(cache_dir), wp.ScopedDevice(self._wp_device):
            # One eager step compiles and loads the physics kernels; the eager reset of all
            # worlds compiles the reset kernels and undoes that step.
            mjw.step(self._m, self._d)
            self._mask.fill_(True)
            self._reset_masked()
            self._mask.zero_()
            self._graphs[RESET] = self._capture(self._reset_masked)
        wp.synchronize_device(self._wp_device)

    def model_field(self, name: str) -> torch.Tensor:
        field = wp.to_torch(getattr(self._m, name))
        if field.shape[0] != self.num_envs:
            return super().model_field(name)
        return field

    def step(self, nstep: int, controls: torch.Tensor | None = None,
             substep: Callable[[int], None] | None = None) -> None:
        if substep is not None:
            # Torch code between the physics steps: a graph of torch's, one per function.
            self._run((nstep, id(substep)), lambda: self._substeps(nstep, None, substep),
                      with_torch=True)
        else:
            # A graph reads `controls` where it was when captured: one graph per tensor.
            key = nstep if controls is None else (nstep, controls.data_ptr())
            self._run(key, lambda: self._substeps(nstep, controls))
        if self._overflow is not None and self._overflow_names:
            flags = self._overflow
            hit = (flags[:, None] & self._overflow_bits).ne(0)
            self._overflow_counts += hit.sum(dim=0)
            torch.ne(flags & self._corrupting, 0, out=self._overflowed)
            flags.zero_()

    def unstable(self) -> torch.Tensor:
        unstable = super().unstable()
        if self._overflow is not None and self._overflow_names:
            unstable |= self._overflowed
        return unstable

    def pop_overflows(self) -> dict[str, float]:
        if not self._overflow_names:
            return {}
        counts = self._overflow_counts.tolist()
        self._overflow_counts.zero_()
        return {name: n for name, n in zip(self._overflow_names, counts, strict=True) if n}

    def reset_to_defaults(self, mask: torch.Tensor) -> None:
        self._mask_t.copy_(mask)
        self._run(RESET, self._reset_masked)
        if self.model.nsensordata:  # as the cpu backend: a reset env's sensors read 0
            self.sensordata.masked_fill_(mask[:, None], 0.0)

    def close(self) -> None:
        self._graphs.clear()

    # internals -------------------------------------------------------------------------------
    def _substeps(self, nstep: int, controls: torch.Tensor | None = None,
                  substep: Callable[[int], None] | None = None) -> None:
        for k in range(nstep):
            if substep is not None:
                substep(k)
            elif controls is not None:
                wp.copy(self._d.ctrl, wp.from_torch(controls[k]))
            mjw.step(self._m, self._d)

    def _reset_masked(self) -> None:
        mjw.reset_data(self._m, self._d, reset=self._mask)

    def _run(self, key: object, fn: Callable[[], None], with_torch: bool = False) -> None:
        """Replay `fn`'s CUDA graph (captured on first use) on torch's current stream: torch's
        writes to `ctrl` or the mask before it and its reads of `qpos` after it stay in order,
        with no sync or event. Inside a torch CUDA graph capture (`torch.cuda.graph` around a
        whole env step, capture_error_mode="thread_local"), a graph cannot be launched, so
        `fn`'s kernels are recorded into torch's graph instead. `with_torch`: `fn` runs torch
        code too, which warp's capture would not record: it runs eagerly once (torch's
        libraries set up outside a capture), then replays as a torch graph."""
        if not self._wp_device.is_cuda:  # warp's CPU device: debugging without a GPU only
            with wp.ScopedDevice(self._wp_device):
                fn()
            return
        stream = self._torch_stream()
        if torch.cuda.is_current_stream_capturing():
            self._record(fn)
            return
        graph = self._graphs.get(key)
        if graph is None and with_torch:
            if key not in self._graphs:
                self._graphs[key] = None  # eager this once
                with wp.ScopedStream(stream, sync_enter=False):
                    fn()
                return
            graph = self._graphs[key] = torch.cuda.CUDAGraph()
            with torch.cuda.graph(graph, capture_error_mode="thread_local"):
                self._record(fn)
        elif graph is None:
            graph = self._graphs[key] = self._capture(fn)
        if isinstance(graph, torch.cuda.CUDAGraph):
            graph.replay()
        else:
            wp.capture_launch(graph, stream=stream)

    def _record(self, fn: Callable[[], None]) -> None:
        """`fn`'s kernels into the torch graph being captured on the current stream."""
        stream = self._torch_stream()
        with (wp.ScopedStream(stream, sync_enter=False),
              wp.ScopedCapture(stream=stream, external=True)):
            fn()

    def _capture(self, fn: Callable[[], None]) -> wp.Graph | None:
        """Record `fn` as a CUDA graph on warp's own stream (capture cannot run on the legacy
        default stream that torch uses); None on warp's CPU device."""
        if not self._wp_device.is_cuda:
            return None
        torch.cuda.current_stream(self.device).synchronize()  # once per graph, at setup
        stream = self._wp_device.stream
        with wp.ScopedStream(stream), wp.ScopedCapture(stream=stream) as capture:
            fn()
        return capture.graph

    def _torch_stream(self) -> wp.Stream:
        """torch's current stream on this device, as a warp stream (one wrapper per stream)."""
        torch_stream = torch.cuda.current_stream(self.device)
        stream = self._streams.get(torch_stream.cuda_stream)
        if stream is None:
            stream = self._streams[torch_stream.cuda_stream] = wp.stream_from_torch(torch_stream)
        return stream
