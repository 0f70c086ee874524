"""lab's warp backend against a raw MuJoCo Warp loop on the same model, in env-steps/s.

  python bench/bench_warp.py [--task cartpole] [--sizes 4096,16384,65536] [--out DIR]
  python bench/bench_warp.py --startup          (seconds to build the env and take a step)
  python bench/bench_warp.py --profile          (host time per env step, by part)
  python bench/bench_warp.py --train rsl_rl [--train-envs 4096] [--out DIR]
                                                (seconds for `lab train` to reach success 0.95)

lab:  `LabVecEnv.step` with a policy's actions (torch MLP on the observations plus noise): task
      terms, terminations, statistics and masked resets included. As users get it (the env
      replays its step as one CUDA graph after three eager steps), and again with
      `env.cuda_graph=false` (every step launched eagerly from Python).
raw:  the RL loop of ../shared/peers/bench_gpu.py ("rl") on the task's own model: torch MLP ->
      ctrl (zero-copy) -> CUDA graph of `decimation` physics steps -> done/reward in torch ->
      captured masked `reset_data` -> random state for the reset worlds. No task code, no stats.
Both: env-steps/s = num_envs * steps / seconds, timed with CUDA events, median of 3 repeats.
Also counts host syncs per lab step (torch's sync debug mode); any sync stalls the pipeline.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import tarfile
import tempfile
import time
import warnings
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

import torch

from labcli.envs import metrics
from labcli.envs.env import LabVecEnv
from labcli.plugins import registry
from labcli.runs.bench import time_to_success

SUCCESS = 0.95


def steps_for(num_envs: int) -> int:
    """Env steps per timed repeat: about 1-3 M env-steps of work, 20..300 steps (as the peer)."""
    return int(max(20, min(300, 3_000_000 // num_envs)))


def mlp(n_in: int, n_out: int) -> torch.nn.Module:
    return torch.nn.Sequential(torch.nn.Linear(n_in, 64), torch.nn.ELU(), torch.nn.Linear(64, 64),
                               torch.nn.ELU(), torch.nn.Linear(64, n_out)).cuda()


def timed(body: Callable[[], None], steps: int, repeats: int = 3, warmup: int = 5) -> float:
    """Median seconds of `steps` calls of `body`, on CUDA events (no host clock in the loop)."""
    for _ in range(warmup):
        body()
    times = []
    for _ in range(repeats):
        start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        start.record()
        for _ in range(steps):
            body()
        end.record()
        end.synchronize()
        times.append(start.elapsed_time(end) / 1e3)
    return statistics.median(times)


def make_env(task: str, num_envs: int, cuda_graph: bool = True) -> LabVecEnv:
    spec = registry.get_task(task)
    return LabVecEnv(spec, spec.config_class(num_envs=num_envs, cuda_graph=cuda_graph),
                     backend="warp", device="cuda")


def lab_loop(task: str, num_envs: int, steps: int, cuda_graph: bool = True) -> dict:
    """`env.step(policy(obs) + noise)` with the env's step replayed as a CUDA graph (the
    default), or launched eagerly (`cuda_graph=False`); the policy runs eagerly in both."""
    env = make_env(task, num_envs, cuda_graph)
    n_act = env.single_action_space.shape[0]
    policy = mlp(env.single_observation_space.shape[0], n_act)
    gen = torch.Generator(device="cuda").manual_seed(0)
    obs, _ = env.reset(seed=0)

    @torch.no_grad()
    def step() -> None:
        noise = 0.5 * torch.randn(num_envs, n_act, device="cuda", generator=gen)
        next_obs, *_ = env.step((policy(obs) + noise).clamp(-1.0, 1.0))
        obs.copy_(next_obs)

    key = "lab" if cuda_graph else "lab_eager"
    out = {key: num_envs * steps / timed(step, steps),
           key + "_syncs_per_step": count_syncs(step, 10)}
    out[key + "_episodes"] = env.pop_stats().get(metrics.EPISODES, 0.0)
    env.close()
    return out


def count_syncs(body: Callable[[], None], steps: int) -> float:
    """Host syncs per call of `body`, as torch's sync debug mode reports them."""
    torch.cuda.synchronize()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        torch.cuda.set_sync_debug_mode("warn")
        try:
            for _ in range(steps):
                body()
        finally:
            torch.cuda.set_sync_debug_mode("default")
    # Not the warning that the mode itself is a prototype: only the syncs it reports.
    syncs = [w for w in caught if "called a synchronizing" in str(w.message)]
    if syncs:
        print(f"  host sync in lab's step, e.g. at {syncs[0].filename}:{syncs[0].lineno}: "
              f"{str(syncs[0].message)[:120]}")
    return len(syncs) / steps


def raw_loop(task: str, num_envs: int, steps: int) -> dict:
    """bench_gpu.py's `rl` protocol on the task's model, with lab's njmax/nconmax."""
    import mujoco
    import mujoco_warp as mjw
    import warp as wp

    from labcli.envs.sim.warp import constraint_capacity, init_warp

    spec = registry.get_task(task)
    cfg = spec.config_class(num_envs=num_envs)
    init_warp()
    mjm = mujoco.MjModel.from_xml_path(str(spec.model))
    if cfg.sim_dt is not None:
        mjm.opt.timestep = cfg.sim_dt
    mjd = mujoco.MjData(mjm)
    mujoco.mj_forward(mjm, mjd)
    stream = torch.cuda.Stream()
    with torch.cuda.stream(stream), wp.ScopedStream(wp.stream_from_torch(stream)):
        m = mjw.put_model(mjm)
        d = mjw.put_data(mjm, mjd, nworld=num_envs, **constraint_capacity(
            mjm, m.nxn_geom_pair_filtered.shape[0] > 0))
        qpos, qvel, ctrl = wp.to_torch(d.qpos), wp.to_torch(d.qvel), wp.to_torch(d.ctrl)
        mask = wp.zeros(num_envs, dtype=bool)
        mask_t = wp.to_torch(mask)

        def capture(fn: Callable[[], None]) -> wp.Graph:
            fn()
            wp.synchronize_stream(wp.get_stream())
            with wp.ScopedCapture() as cap:
                fn()
            return cap.graph

        physics = capture(lambda: [mjw.step(m, d) for _ in range(cfg.decimation)])
        reset = capture(lambda: mjw.reset_data(m, d, reset=mask))
        policy = mlp(mjm.nq + mjm.nv, mjm.nu)
        gen = torch.Generator(device="cuda").manual_seed(0)
        reward_sum = torch.zeros(num_envs, device="cuda")
        bound = getattr(cfg, "cart_bound", 3.0)

        @torch.no_grad()
        def step() -> None:
            obs = torch.cat([qpos, qvel], dim=1)
            act = policy(obs) + 0.5 * torch.randn(num_envs, mjm.nu, device="cuda", generator=gen)
            ctrl.copy_(act.clamp(-1.0, 1.0) * cfg.action_scale)
            wp.capture_launch(physics)
            done = qpos[:, 0].abs() > bound
            reward_sum.add_((~done).float())
            mask_t.copy_(done)
            wp.capture_launch(reset)
            dm = done[:, None].float()
            qpos.add_(dm * (torch.rand(qpos.shape, device="cuda", generator=gen) * 2 - 1) * 0.5)
            qvel.add_(dm * (torch.rand(qvel.shape, device="cuda", generator=gen) * 2 - 1) * 0.5)

        seconds = timed(step, steps)
    return {"raw": num_envs * steps / seconds}


def startup(task: str, num_envs: int) -> None:
    """Seconds to import MuJoCo Warp, build the env (kernels compiled or loaded) and step it."""
    start = time.perf_counter()
    import labcli.envs.sim.warp  # noqa: F401  (warp and mujoco_warp)

    imported = time.perf_counter()
    env = make_env(task, num_envs)
    built = time.perf_counter()
    env.reset(seed=0)
    env.step(torch.zeros(num_envs, env.single_action_space.shape[0], device="cuda"))
    torch.cuda.synchronize()
    done = time.perf_counter()
    print(f"startup: import {imported - start:.1f} s, env built {built - imported:.1f} s, first "
          f"step {done - built:.1f} s; total {done - start:.1f} s ({num_envs} envs)")


def host_profile(task: str, num_envs: int, steps: int = 200) -> None:
    """Host (Python + launch) microseconds per env step, by part of the step. At a size where
    the GPU keeps up, this is what bounds lab's eager env-steps/s (replayed as a CUDA graph, the
    step costs one launch)."""
    env = make_env(task, num_envs, cuda_graph=False)
    policy = mlp(env.single_observation_space.shape[0], env.single_action_space.shape[0])
    totals: dict[str, float] = defaultdict(float)

    def wrap(owner: object, name: str, label: str) -> None:
        fn = getattr(owner, name)

        def timed_fn(*args, **kwargs):
            t = time.perf_counter()
            out = fn(*args, **kwargs)
            totals[label] += time.perf_counter() - t
            return out

        setattr(owner, name, timed_fn)

    for name in ("step", "reset_to_defaults", "unstable"):
        wrap(env.sim, name, f"sim.{name}")
    for name in ("apply_actions", "observations", "reward_terms", "terminations", "reset",
                 "success"):
        wrap(env.task, name, f"task.{name}")
    wrap(env, "_accumulate", "env._accumulate")
    obs, _ = env.reset(seed=0)
    with torch.no_grad():
        for i in range(steps + 20):
            if i == 20:  # after warm-up
                totals.clear()
                torch.cuda.synchronize()
            t0 = time.perf_counter()
            actions = (policy(obs) + 0.5 * torch.randn_like(obs[:, :1])).clamp(-1.0, 1.0)
            t1 = time.perf_counter()
            obs, *_ = env.step(actions)
            t2 = time.perf_counter()
            totals["policy (bench)"] += t1 - t0
            totals["env.step"] += t2 - t1
    torch.cuda.synchronize()
    parts = {k: v for k, v in totals.items() if k not in ("policy (bench)", "env.step")}
    totals["env.step: the rest"] = totals["env.step"] - sum(parts.values())
    print(f"host time per env step at {num_envs} envs (us):")
    for label, seconds in sorted(totals.items(), key=lambda kv: -kv[1]):
        print(f"  {label:<28} {seconds / steps * 1e6:8.1f}")
    env.close()


def train(task: str, framework: str, num_envs: int, out: Path | None) -> None:
    """`lab train --backend warp` as a user runs it, in a throwaway logs dir: process wall time
    (kernels load from the cache: run the bench once before), and the training seconds and
    steps until the logged success rate first reached SUCCESS. With `out`, the run dir is
    packed there as run.tgz, to play it on another machine."""
    with tempfile.TemporaryDirectory(prefix="bench_warp_") as logs:
        cmd = ["lab", "train", "--task", task, "--framework", framework, "--backend", "warp",
               "--num-envs", str(num_envs)]
        start = time.perf_counter()
        done = subprocess.run(cmd, env={**os.environ, "LAB_LOGS_DIR": logs}, capture_output=True,
                              text=True)
        wall = time.perf_counter() - start
        print(done.stdout.strip(), done.stderr.strip()[-2000:] if done.returncode else "")
        (run_dir,) = Path(logs, framework, task).iterdir()
        summary = json.loads((run_dir / "summary.json").read_text())
        success = time_to_success(run_dir, SUCCESS)
        reached = (f"success >= {SUCCESS} after {success[0]:.1f} s of training, {success[1]:,} "
                   "steps" if success else f"success never reached {SUCCESS}")
        print(f"{shlex.join(cmd)}: {wall:.1f} s in all, {summary['wall_time_s']:.1f} s training,"
              f" {summary['steps']:,} steps, final success {summary['success_rate']}; {reached}")
        if out:
            out.mkdir(parents=True, exist_ok=True)
            with tarfile.open(out / f"run_{framework}.tgz", "w:gz") as tar:
                tar.add(run_dir, arcname=run_dir.name)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="cartpole")
    p.add_argument("--sizes", default="4096,16384,65536")
    p.add_argument("--startup", action="store_true", help="only time building the env")
    p.add_argument("--profile", action="store_true",
                   help="only break lab's host time per step down by part, at 1024 envs")
    p.add_argument("--train", metavar="FRAMEWORK", help="only time `lab train` to success")
    p.add_argument("--train-envs", type=int, default=4096)
    p.add_argument("--out", type=Path, help="write results.json (or the trained run) here")
    a = p.parse_args()
    if a.train:
        train(a.task, a.train, a.train_envs, a.out)
        return
    if a.startup:
        startup(a.task, 4096)
        return
    if a.profile:
        host_profile(a.task, 1024)
        return
    print(f"torch {torch.__version__} on {torch.cuda.get_device_name()}; task {a.task}")
    rows = []
    for n in (int(s) for s in a.sizes.split(",") if s):
        steps = steps_for(n)
        row = {"num_envs": n, "steps": steps, **raw_loop(a.task, n, steps),
               **lab_loop(a.task, n, steps), **lab_loop(a.task, n, steps, cuda_graph=False)}
        row["ratio"] = row["lab"] / row["raw"]
        row["ratio_eager"] = row["lab_eager"] / row["raw"]
        rows.append(row)
        print(f"{n:>7} envs | raw {row['raw']:>12,.0f} | lab {row['lab']:>12,.0f} "
              f"({row['ratio']:.0%} of raw) | lab, eager step {row['lab_eager']:>12,.0f} "
              f"({row['ratio_eager']:.0%}) env-steps/s | host syncs per lab step "
              f"{row['lab_syncs_per_step']:g} (eager {row['lab_eager_syncs_per_step']:g})",
              flush=True)
        torch.cuda.empty_cache()
    if a.out:
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / "bench_warp.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
