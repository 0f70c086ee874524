"""lab's cpu backend beside what users run today, measured in one run on one machine.

  python bench/bench_cpu.py [--envs 16,256,1024] [--seconds 3] [--repeats 3] [--peers DIR]
                            [--frameworks sb3,rsl_rl,skrl,rl_games] [--skip-train] [--json FILE]
  python bench/bench_cpu.py --profile 256     (only: lab's env step by part, in microseconds)
  python bench/bench_cpu.py --threads 2,4,8,16 [--tasks cartpole,ant,humanoid] [--envs 1024,4096]
                            [--train rsl_rl]    (only d)

a) env-steps/s of lab's cartpole (`LabVecEnv`, cpu backend, random actions, autoreset, torch
   tensors out) beside ../shared/peers/bench_step.py (run as a subprocess: raw `mujoco.rollout`,
   gymnasium sync/async vector envs of InvertedPendulum-v5) and beside raw `mujoco.rollout` on
   lab's own cartpole model with the same frame skip, measured here with the peer's protocol.
b) the SB3 / RSL-RL / skrl / rl_games adapters' cost per step at 256 envs, over the raw env's.
c) time until `lab train --task cartpole --framework F` first logs Metrics/success_rate >= 0.95
   (from its TensorBoard events), beside the peers' train_sb3_gym.py / train_rsl_rl_gym.py
   (seconds until mean return 950 on InvertedPendulum-v5: another criterion, so a rough ratio).
d) with --threads: lab's env-steps/s of each task at each thread count beside raw
   `mujoco.rollout` of what the env steps on as many threads (`lab bench --threads`), and with
   --train the training steps/s of cartpole with that framework at each thread count; with
   --steps eager,compiled the env step eager and compiled (`env.compile`) in turn.

Machines are noisy: each throughput figure is the median of --repeats interleaved runs, and the
load average is printed before and after. Nothing here asserts a timing; it prints figures.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import mujoco
import numpy as np
import torch
from mujoco import rollout
from rich.console import Console
from rich.table import Table

from labcli.envs.env import LabVecEnv
from labcli.envs.make import make_env as make_lab_env
from labcli.envs.shards import ShardedVecEnv
from labcli.plugins import registry
from labcli.plugins.policy import one_torch_thread
from labcli.runs.bench import bench, cpu_name, env_rate, rate, time_to_success

REPO = Path(__file__).resolve().parents[1]
TASK = "cartpole"
ADAPTER_ENVS = 256
SUCCESS = 0.95
DISTRIBUTIONS = ("mujoco", "torch", "stable-baselines3", "rsl-rl-lib", "skrl", "rl-games",
                 "gymnasium")
# bench_step.py's lines, e.g. "rollout           N=256         38,954 env-steps/s".
PEER_LINE = re.compile(r"^(\S+)\s+N=(\d+)\s+([\d,]+) env-steps/s")
PEER_TRAIN_LINE = re.compile(r"solved in ([\d.]+) s, ([\d,]+) steps")
# The peer training script of each framework, where there is one.
PEER_TRAIN = {"sb3": "train_sb3_gym.py", "rsl_rl": "train_rsl_rl_gym.py"}

# Off a terminal (a log, a pipe) rich would wrap the tables at 80 columns.
console = Console(width=None if sys.stdout.isatty() else 150)


# Timing ---------------------------------------------------------------------------------------
def make_env(num_envs: int) -> LabVecEnv | ShardedVecEnv:
    """The env `lab train` steps: in shards on two threads or more (128 envs or more)."""
    spec = registry.get_task(TASK)
    return make_lab_env(spec, spec.config_class(num_envs=num_envs), backend="cpu", seed=0)


def lab_rate(num_envs: int, seconds: float) -> float:
    env = make_env(num_envs)
    try:
        return env_rate(env, seconds)
    finally:
        env.close()


def rollout_rate(num_envs: int, seconds: float) -> float:
    """bench_step.py's `raw_rollout` protocol on lab's cartpole model: one `mujoco.rollout` per
    env step over all envs (nthread = cores), decimation physics steps of random controls, the
    state copied out, envs whose cart left the rail put back at the initial state."""
    spec = registry.get_task(TASK)
    cfg = spec.config_class(num_envs=num_envs)
    model = mujoco.MjModel.from_xml_path(str(spec.model))
    nthread = os.cpu_count() or 1
    datas = [mujoco.MjData(model) for _ in range(nthread)]
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    initial = np.empty(mujoco.mj_stateSize(model, full))
    mujoco.mj_getState(model, datas[0], initial, full)
    state = np.tile(initial, (num_envs, 1))
    cart = 1  # the cart's qpos follows time in the state vector
    runner = rollout.Rollout(nthread=nthread)
    rng = np.random.default_rng(0)

    def step() -> int:
        nonlocal state
        ctrl = rng.uniform(-1, 1, (num_envs, cfg.decimation, model.nu)) * cfg.action_scale
        states, _ = runner.rollout(model, datas, state, ctrl, nstep=cfg.decimation)
        state = states[:, -1, :].copy()
        state[np.abs(state[:, cart]) > cfg.cart_bound] = initial
        return num_envs

    try:
        return rate(step, seconds)
    finally:
        runner.close()


def run_peer_step(peers: Path, envs: list[int], seconds: float) -> dict[tuple[str, int], float]:
    """bench_step.py's figures, keyed by (what, N)."""
    out = subprocess.run(
        [sys.executable, str(peers / "bench_step.py"), "--envs", ",".join(map(str, envs)),
         "--seconds", str(seconds)], capture_output=True, text=True, check=True).stdout
    found = {}
    for line in out.splitlines():
        match = PEER_LINE.match(line)
        if match:
            found[match[1], int(match[2])] = float(match[3].replace(",", ""))
    return found


def throughput(envs: list[int], seconds: float, repeats: int,
               peers: Path) -> dict[tuple[str, int], float]:
    """Median env-steps/s by (what, N), the repeats interleaved so drift hits all alike."""
    runs: dict[tuple[str, int], list[float]] = defaultdict(list)
    for repeat in range(repeats):
        console.print(f"  throughput, repeat {repeat + 1}/{repeats}", highlight=False)
        for key, value in run_peer_step(peers, envs, seconds).items():
            runs[key].append(value)
        for n in envs:
            runs["lab", n].append(lab_rate(n, seconds))
            runs["rollout-lab-model", n].append(rollout_rate(n, seconds))
    return {key: statistics.median(values) for key, values in runs.items()}


# Adapters -------------------------------------------------------------------------------------
def adapter_steppers(env: LabVecEnv | ShardedVecEnv) -> dict[str, Callable[[], int]]:
    """One env step through each framework's adapter, with the actions that library passes."""
    from lab_rl_games.adapter import RlGamesVecEnv
    from lab_rsl_rl.adapter import RslRlVecEnv
    from lab_sb3.adapter import Sb3VecEnv
    from lab_skrl.adapter import SkrlEnv

    n, act = env.num_envs, env.single_action_space.shape[0]
    gen = torch.Generator().manual_seed(0)
    rng = np.random.default_rng(0)
    sb3, rsl, skrl, rlg = Sb3VecEnv(env), RslRlVecEnv(env), SkrlEnv(env), RlGamesVecEnv(env)
    sb3.reset()
    skrl.reset()

    def torch_actions() -> torch.Tensor:
        return torch.rand((n, act), generator=gen) * 2 - 1

    def stepper(fn: Callable[[], object]) -> Callable[[], int]:
        def step() -> int:
            fn()
            return n

        return step

    return {
        "raw env": stepper(lambda: env.step(torch_actions())),
        "sb3 (numpy)": stepper(lambda: sb3.step(rng.uniform(-1, 1, (n, act)).astype(np.float32))),
        "rsl_rl": stepper(lambda: rsl.step(torch_actions())),
        "skrl": stepper(lambda: skrl.step(torch_actions())),
        "rl_games": stepper(lambda: rlg.step(torch_actions())),
    }


def adapter_rates(seconds: float, repeats: int) -> dict[str, float]:
    env = make_env(ADAPTER_ENVS)
    env.reset(seed=0)
    steppers = adapter_steppers(env)
    runs: dict[str, list[float]] = defaultdict(list)
    with one_torch_thread("cpu"):  # as lab's learners step their envs
        for _ in range(repeats):
            for name, step in steppers.items():
                runs[name].append(rate(step, seconds))
    env.close()
    return {name: statistics.median(values) for name, values in runs.items()}


# Training -------------------------------------------------------------------------------------
def train_lab(framework: str) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench_cpu_") as logs:
        start = time.perf_counter()
        subprocess.run(["lab", "train", "--task", TASK, "--framework", framework],
                       env={**os.environ, "LAB_LOGS_DIR": logs}, cwd=logs, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wall = time.perf_counter() - start
        (run_dir,) = Path(logs, framework, TASK).iterdir()
        summary = json.loads((run_dir / "summary.json").read_text())
        success = time_to_success(run_dir, SUCCESS)
    return {"wall_s": wall, "train_s": summary["wall_time_s"], "steps": summary["steps"],
            "success_rate": summary["success_rate"],
            "success_s": success[0] if success else None,
            "success_steps": success[1] if success else None}


def train_peer(script: Path) -> dict:
    """A peer training script's seconds and steps to its own criterion (None: not reached)."""
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         check=True).stdout.strip()
    match = PEER_TRAIN_LINE.search(out)
    return {"line": out,
            "solved_s": float(match[1]) if match else None,
            "solved_steps": int(match[2].replace(",", "")) if match else None}


# Profile --------------------------------------------------------------------------------------
TASK_PARTS = ("apply_actions", "update", "observations", "reward_terms", "terminations", "reset",
              "success")


def profile(num_envs: int, steps: int = 300) -> dict[str, float]:
    """Per-step microseconds of `sim.step` (the rollout), of the task's methods and of the rest
    (the env's own code), with each method wrapped by a timer; median over blocks of steps. In
    one process (where a shard's parts run beside the others', they would not add up)."""
    spec = registry.get_task(TASK)
    env = LabVecEnv(spec, spec.config_class(num_envs=num_envs), backend="cpu", seed=0)
    env.reset(seed=0)
    totals: dict[str, float] = defaultdict(float)

    def timed(owner: object, name: str, part: str) -> None:
        fn = getattr(owner, name)

        def call(*args, **kwargs):
            start = time.perf_counter()
            out = fn(*args, **kwargs)
            totals[part] += time.perf_counter() - start
            return out

        setattr(owner, name, call)

    timed(env.sim, "step", "sim.step (rollout)")
    for name in TASK_PARTS:
        timed(env.task, name, "task")
    blocks, per_block = [], max(1, steps // 10)
    # On one torch thread, as `lab_rate` and the learners step: on 16 cores torch's own threads
    # made `sim.step` of 4,096 envs take 6.5 ms against the rollout's 4.0 ms.
    with one_torch_thread("cpu"):
        for _ in range(12):
            totals.clear()
            start = time.perf_counter()
            for _ in range(per_block):
                env.step(torch.rand(num_envs, env.single_action_space.shape[0]) * 2 - 1)
            step = time.perf_counter() - start
            parts = {"sim.step (rollout)": totals["sim.step (rollout)"], "task": totals["task"],
                     "env (the rest)": step - sum(totals.values()), "whole step": step}
            blocks.append({k: v / per_block * 1e6 for k, v in parts.items()})
    env.close()
    return {k: statistics.median(b[k] for b in blocks[2:]) for k in blocks[0]}


def profile_table(num_envs: int, parts: dict[str, float]) -> None:
    table = Table(title=f"lab's env step at {num_envs} envs")
    table.add_column("part")
    table.add_column("us per step", justify="right")
    for name, us in parts.items():
        table.add_row(name, f"{us:,.0f}")
    console.print(table)


# Threads --------------------------------------------------------------------------------------
def thread_rates(tasks: list[str], envs: list[int], threads: list[int], seconds: float,
                 repeats: int, framework: str | None, steps: list[str]
                 ) -> dict[tuple[str, str, int, int], dict]:
    """Medians by (task, step, threads, N) of lab's and the rollout's env-steps/s and their
    ratio, the repeats interleaved; `steps`: "eager" and/or "compiled" (`env.compile`); with
    `framework`, cartpole's training steps/s too."""
    runs: dict[tuple[str, str, int, int], dict[str, list[float]]] = defaultdict(
        lambda: defaultdict(list))
    for repeat in range(repeats):
        console.print(f"  threads, repeat {repeat + 1}/{repeats}", highlight=False)
        for task, step in itertools.product(tasks, steps):
            for row in bench(task, envs, backend="cpu", seconds=seconds, threads=threads,
                             framework=framework if task == TASK else None,
                             overrides=[f"env.compile={step == 'compiled'}"]):
                figures = runs[task, step, row.threads, row.num_envs]
                figures["lab"].append(row.env_steps_per_s)
                figures["rollout"].append(row.rollout_steps_per_s)
                figures["ratio"].append(row.ratio_to_rollout)
                if row.train_steps_per_s is not None:
                    figures["train"].append(row.train_steps_per_s)
    return {key: {what: statistics.median(values) for what, values in figures.items()}
            for key, figures in runs.items()}


def thread_table(rates: dict[tuple[str, str, int, int], dict], framework: str | None) -> None:
    table = Table(title="d) env-steps/s by physics threads, lab beside mujoco.rollout (median)")
    for col in ("task", "step", "threads", "N", "lab", "rollout", "lab / rollout"):
        table.add_column(col, justify="right")
    if framework:
        table.add_column(f"{framework} training steps/s", justify="right")
    for (task, step, threads, n), r in rates.items():
        cells = [task, step, str(threads), str(n), fmt(r["lab"]), fmt(r["rollout"]),
                 f"{r['ratio']:.2f}"]
        if framework:
            cells.append(fmt(r.get("train")))
        table.add_row(*cells)
    console.print(table)


# Report ---------------------------------------------------------------------------------------
def header() -> dict:
    cpu = cpu_name()
    versions = {}
    for dist in DISTRIBUTIONS:
        try:
            versions[dist] = version(dist)
        except PackageNotFoundError:
            versions[dist] = "not installed"
    info = {"cores": os.cpu_count(), "cpu": cpu, "python": platform.python_version(),
            "torch_threads": torch.get_num_threads(), "versions": versions,
            "load_before": os.getloadavg()}
    console.print(f"machine: {info['cores']} cores ({cpu}), python {info['python']}, torch "
                  f"intra-op threads {info['torch_threads']}", highlight=False)
    console.print("versions: " + ", ".join(f"{k} {v}" for k, v in versions.items()),
                  highlight=False)
    console.print(f"load average before: {fmt_load(info['load_before'])}", highlight=False)
    return info


def fmt_load(load: tuple[float, ...]) -> str:
    return " ".join(f"{x:.2f}" for x in load) + f" (over {os.cpu_count()} cores)"


def fmt(value: float | None, spec: str = ",.0f") -> str:
    return "-" if value is None else format(value, spec)


def ratio(a: float | None, b: float | None) -> str:
    return "-" if not a or not b else f"{a / b:.2f}"


def throughput_table(rates: dict[tuple[str, int], float], envs: list[int]) -> None:
    table = Table(title="a) env-steps/s, random actions, autoreset included (median)")
    for col in ("N", "lab", "rollout, lab's model", "rollout, gym model", "gym-sync",
                "gym-async", "lab / rollout (lab's model)", "lab / gym-sync"):
        table.add_column(col, justify="right")
    for n in envs:
        lab = rates.get(("lab", n))
        own = rates.get(("rollout-lab-model", n))
        sync = rates.get(("gym-sync", n))
        table.add_row(str(n), fmt(lab), fmt(own), fmt(rates.get(("rollout", n))), fmt(sync),
                      fmt(rates.get(("gym-async", n))), ratio(lab, own), ratio(lab, sync))
    console.print(table)
    single = rates.get(("raw-c-1core", 1))
    if single:
        console.print(f"peer raw-c-1core (mj_step loop, gym model, N=1): {single:,.0f}",
                      highlight=False)


def adapter_table(rates: dict[str, float]) -> None:
    table = Table(title=f"b) adapters at {ADAPTER_ENVS} envs (median)")
    for col in ("through", "env-steps/s", "time per step / raw env's"):
        table.add_column(col, justify="right")
    raw = rates["raw env"]
    for name, value in rates.items():
        table.add_row(name, fmt(value), ratio(raw, value))
    console.print(table)


def train_table(lab: dict[str, dict], peers: dict[str, dict]) -> None:
    table = Table(title=f"c) lab train --task {TASK}: time to success rate >= {SUCCESS}")
    for col in ("framework", "wall (process)", "training (summary)", "steps", "final success",
                f"s to >= {SUCCESS}", f"steps to >= {SUCCESS}", "peer s to return 950",
                "peer steps", "lab s / peer s"):
        table.add_column(col, justify="right")
    for fw, r in lab.items():
        peer = peers.get(fw, {})
        table.add_row(fw, fmt(r["wall_s"], ".1f"), fmt(r["train_s"], ".1f"), fmt(r["steps"]),
                      fmt(r["success_rate"], ".2f"), fmt(r["success_s"], ".1f"),
                      fmt(r["success_steps"]), fmt(peer.get("solved_s"), ".1f"),
                      fmt(peer.get("solved_steps")), ratio(r["success_s"], peer.get("solved_s")))
    console.print(table)
    for fw, peer in peers.items():
        console.print(f"peer {PEER_TRAIN[fw]}: {peer['line']}", highlight=False)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", default="16,256,1024")
    p.add_argument("--seconds", type=float, default=3.0, help="per throughput measurement")
    p.add_argument("--repeats", type=int, default=3, help="interleaved runs; medians reported")
    p.add_argument("--peers", type=Path, default=REPO.parent / "shared" / "peers")
    p.add_argument("--frameworks", default="sb3,rsl_rl,skrl,rl_games")
    p.add_argument("--skip-train", action="store_true")
    p.add_argument("--json", type=Path, help="also write the figures here")
    p.add_argument("--profile", type=int, metavar="N",
                   help="only break lab's env step down by part at N envs")
    p.add_argument("--threads", help="only d): these physics thread counts, e.g. 2,4,8,16")
    p.add_argument("--tasks", default=TASK, help="d)'s tasks, e.g. cartpole,ant,humanoid")
    p.add_argument("--steps", default="eager", help="d): the env step eager, compiled "
                   "(env.compile) or both in turn: eager,compiled")
    p.add_argument("--train", metavar="FRAMEWORK", help="d): also cartpole's training steps/s")
    a = p.parse_args()
    if a.train and TASK not in a.tasks.split(","):
        p.error(f"--train times {TASK}'s training: list it in --tasks")
    if not set(a.steps.split(",")) <= {"eager", "compiled"}:
        p.error(f"--steps takes eager, compiled or eager,compiled, got {a.steps}")
    if a.profile:
        profile_table(a.profile, profile(a.profile))
        return
    envs = [int(x) for x in a.envs.split(",") if x]
    results: dict = {"command": " ".join(sys.argv), "machine": header()}
    if a.threads:
        rates = thread_rates(a.tasks.split(","), envs, [int(t) for t in a.threads.split(",")],
                             a.seconds, a.repeats, a.train, a.steps.split(","))
        thread_table(rates, a.train)
        results["threads"] = {f"{task}@{step}@{t}@{n}": r
                              for (task, step, t, n), r in rates.items()}
        finish(results, a.json)
        return

    rates = throughput(envs, a.seconds, a.repeats, a.peers)
    throughput_table(rates, envs)
    results["throughput"] = {f"{what}@{n}": v for (what, n), v in rates.items()}

    results["adapters"] = adapter_rates(a.seconds, a.repeats)
    adapter_table(results["adapters"])

    if not a.skip_train:
        frameworks = [f for f in a.frameworks.split(",") if f]
        lab = {fw: train_lab(fw) for fw in frameworks}
        peers = {fw: train_peer(a.peers / PEER_TRAIN[fw]) for fw in frameworks
                 if fw in PEER_TRAIN}
        train_table(lab, peers)
        results["train"], results["train_peers"] = lab, peers

    finish(results, a.json)


def finish(results: dict, path: Path | None) -> None:
    results["machine"]["load_after"] = os.getloadavg()
    console.print(f"load average after: {fmt_load(results['machine']['load_after'])}",
                  highlight=False)
    if path:
        path.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
