"""The conformance suites: checks every framework plugin and every task plugin must pass,
built-in or not.

A framework plugin's own tests call `check_framework("myfw", tmp_path, SMALL)` (or the single
checks) with `--set` overrides that make its agent tiny. Each check trains the real cartpole task
at a small size and fails with an AssertionError that names the framework and what it got wrong.
A task plugin's call `check_task("mytask")`: below, after the framework checks.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rich.console import Console

from labcli.envs import make, metrics, wrappers
from labcli.envs.env import LabVecEnv
from labcli.envs.wrappers import Stage
from labcli.plugins import registry
from labcli.plugins.framework import Checkpoint, FrameworkSpec
from labcli.plugins.policy import Policy
from labcli.runs import checkpoints, config, loading, rundir, training
from labcli.runs.plot import read_scalars
from labcli.runs.session import TrainOutcome

TASK = "cartpole"
NUM_ENVS = 4
# Cartpole steps 0.02 s: 0.1 s episodes time out after 5 steps, so every iteration ends some.
SHORT_EPISODE = "env.episode_length_s=0.1"
# The built-in frameworks at the smallest sizes that still run every code path: a few seconds of
# training for tests that exercise the machinery around learning, not the learning.
SB3_OFF_POLICY = ["agent.train_freq=8", "agent.gradient_steps=4", "agent.batch_size=16",
                  "agent.learning_starts=16", "agent.buffer_size=256", "agent.net_arch=[16]"]
SMALL_AGENTS = {
    # VecNormalize on, whatever the task's default: its statistics are what checkpoints, resume
    # and export most easily get wrong.
    "sb3": ["agent.n_steps=8", "agent.batch_size=16", "agent.n_epochs=2", "agent.net_arch=[16]",
            "agent.normalize_obs=true"],
    "rsl_rl": ["agent.num_steps_per_env=8", "agent.num_learning_epochs=2",
               "agent.num_mini_batches=2", "agent.actor_hidden_dims=[16]",
               "agent.critic_hidden_dims=[16]"],
    "skrl": ["agent.rollouts=8", "agent.learning_epochs=2", "agent.mini_batches=2",
             "agent.hidden_sizes=[16]"],
    # Updates from the fifth step on, so that every check's first iteration has some.
    "skrl_sac": ["agent.rollouts=8", "agent.batch_size=16", "agent.learning_starts=4",
                 "agent.buffer_size=256", "agent.hidden_sizes=[16]"],
    "skrl_td3": ["agent.rollouts=8", "agent.batch_size=16", "agent.learning_starts=4",
                 "agent.buffer_size=256", "agent.hidden_sizes=[16]"],
    # SB3 counts learning_starts in steps of all envs: updates from the first iteration's end.
    "sb3_sac": SB3_OFF_POLICY,
    "sb3_td3": SB3_OFF_POLICY,
    "rl_games": ["agent.horizon_length=8", "agent.mini_epochs=2",
                 "agent.minibatch_size_per_env=4", "agent.units=[16]"],
}
EXPORT_TOLERANCE = 1e-5
# Resumed and unbroken runs do the same float operations in the same order: they agree exactly
# on the CPU; the tolerance only leaves room for a library that reorders a reduction.
RESUME_TOLERANCE = 1e-6


@dataclass
class ProbeStep:
    """One step through an adapter, as the library sees it: anything array-like, `[num_envs]`
    (observations `[num_envs, ...]`). `truncated` are the time-outs the library bootstraps on."""

    obs: Any
    reward: Any
    terminated: Any
    truncated: Any


# Steps the wrapped env (pipeline applied) with the given actions and reports what the library
# receives. Each library exposes time-outs its own way, so the plugin provides this.
Probe = Callable[[Any, torch.Tensor], ProbeStep]


def _array(x: Any) -> np.ndarray:
    return torch.as_tensor(x).detach().cpu().numpy() if not isinstance(x, np.ndarray) else x


def train_small(name: str, logs_dir: Path, iterations: int, overrides: Sequence[str],
                num_envs: int = NUM_ENVS, **kwargs: Any) -> TrainOutcome:
    """A quiet training run of cartpole with framework `name`, for tests (its lines go to
    `console`, if given)."""
    return training.train(TASK, name, num_envs=num_envs, max_iterations=iterations,
                          overrides=list(overrides), logs_dir=logs_dir, seed=kwargs.pop("seed", 0),
                          console=kwargs.pop("console", None) or Console(file=io.StringIO()),
                          command=["lab", "test"], **kwargs)


def make_env(num_envs: int = NUM_ENVS, device: str = "cpu", **cfg: Any) -> LabVecEnv:
    """A cartpole env on `device`'s default backend (the cpu backend on the CPU) with `cfg`
    over the task's defaults, for tests."""
    spec = registry.get_task(TASK)
    return LabVecEnv(spec, spec.config_class(num_envs=num_envs, **cfg), device=device)


def load_policy(name: str, checkpoint: Path, env: Any) -> Policy:
    """Framework `name`'s Policy from `checkpoint`, with the agent config of its run dir, as
    `lab play` loads it."""
    spec = registry.get_framework(name)
    cfg = checkpoints.agent_config(spec, rundir.open_run(checkpoint.parent))
    iteration = int(checkpoint.name.removeprefix(spec.checkpoint_prefix)
                    .removesuffix(spec.checkpoint_suffix))
    return loading.policy_of(spec.load(), Checkpoint(checkpoint, iteration), env, cfg)


def check_adapter(name: str, probe: Probe | None = None) -> None:
    """The framework registers its adapter, its default pipeline validates and wraps a LabVecEnv;
    with a `probe`, zero actions through the adapter give `[num_envs]` batches, and time-outs
    reach the library flagged apart from terminations."""
    spec = registry.get_framework(name)
    assert isinstance(spec, FrameworkSpec), f"{name}: registered object is not a FrameworkSpec"
    owned = list(spec.wrappers)
    adapters = [s for s in owned if s.stage is Stage.ADAPTER]
    assert adapters and owned[0] is adapters[0], f"{name}: wrappers must list its adapter first"
    for wrapper in owned:
        assert registry.get_wrapper(wrapper.name) is wrapper, (
            f"{name}: wrapper {wrapper.name} is not the one registered under its name")
    fw = spec.load()
    cfg = fw.agent_config()
    pipeline = fw.pipeline(cfg)
    wrappers.validate(pipeline, name)  # a LabError names the wrapper out of place
    assert any(step.spec is adapters[0] for step in pipeline), (
        f"{name}: the default pipeline does not use the adapter {adapters[0].name}")
    if probe is None:
        env = make_env()
        try:
            wrappers.apply(env, pipeline, name)
        finally:
            env.close()
        return
    for what, env_cfg, steps, expect_term in (
        ("time-out", {"episode_length_s": 0.1}, 5, False),
        ("termination", {"cart_bound": 0.1, "reset_cart_pos": (0.5, 0.5)}, 1, True),
    ):
        env = make_env(**env_cfg)
        try:
            env.reset(seed=0)  # Gymnasium's contract: reset before the first step
            wrapped = wrappers.apply(env, pipeline, name)
            for i in range(steps):
                got = probe(wrapped, torch.zeros(NUM_ENVS, *env.single_action_space.shape))
                obs, reward = _array(got.obs), _array(got.reward).reshape(-1)
                term, trunc = (_array(got.terminated).reshape(-1).astype(bool),
                               _array(got.truncated).reshape(-1).astype(bool))
                for label, arr in (("observations", obs), ("rewards", reward),
                                   ("terminated", term), ("truncated", trunc)):
                    assert arr.shape[0] == NUM_ENVS, (
                        f"{name}: adapter gave {label} of batch {arr.shape[0]}, not {NUM_ENVS}")
                assert obs.shape[1:] == env.single_observation_space.shape, (
                    f"{name}: adapter observation shape {obs.shape[1:]}")
                if i < steps - 1:
                    assert not (term | trunc).any(), f"{name}: episodes ended early at step {i}"
            assert term.all() == expect_term and not (term & trunc).any(), (
                f"{name}: on a {what}, terminated={term.tolist()} truncated={trunc.tolist()}")
            assert trunc.all() != expect_term, (
                f"{name}: a {what} must {'not ' if expect_term else ''}be flagged as a time-out "
                f"(truncated={trunc.tolist()})")
        finally:
            env.close()


def check_training_outputs(name: str, tmp_path: Path, overrides: Sequence[str] = (),
                           iterations: int = 3) -> TrainOutcome:
    """A few iterations write checkpoints named by `checkpoint_path` at the save interval and at
    the end, a consistent summary.json and manifest (with the version of the framework's
    `library`), and the common TensorBoard tags."""
    fw = registry.get_framework(name)
    outcome = train_small(name, tmp_path, iterations,
                     [*overrides, SHORT_EPISODE, "agent.save_interval=2"])
    run_dir = outcome.run.dir
    expected = [fw.checkpoint_path(run_dir, i) for i in (2, iterations)]
    for path in expected:
        assert path.is_file(), f"{name}: no checkpoint {path.name} in {sorted(run_dir.iterdir())}"
    found = [c.iteration for c in fw.checkpoints(run_dir)]
    assert found == [2, iterations], f"{name}: checkpoints at iterations {found}, not [2, 3]"
    assert not list(run_dir.glob(".tmp_*")), f"{name}: temporary files left in {run_dir}"
    for file in (rundir.ENV_PARAMS, rundir.AGENT_PARAMS, rundir.COMMAND, rundir.MANIFEST,
                 rundir.SUMMARY):
        assert (run_dir / file).is_file(), f"{name}: run dir lacks {file}"
    summary = json.loads((run_dir / rundir.SUMMARY).read_text())
    assert summary["state"] == "finished", f"{name}: summary state {summary['state']}"
    assert summary["iterations"] == iterations, f"{name}: summary iterations {summary}"
    steps = summary["steps"]
    assert steps > 0 and steps % (iterations * NUM_ENVS) == 0, (
        f"{name}: summary steps {steps} is not a whole number of {NUM_ENVS}-env iterations")
    assert summary["checkpoint"] == expected[-1].name, f"{name}: summary {summary['checkpoint']}"
    assert summary["mean_return"] is not None, f"{name}: no episode stats reached the summary"
    manifest = json.loads((run_dir / rundir.MANIFEST).read_text())
    assert manifest["state"] == "finished", f"{name}: manifest state {manifest['state']}"
    if fw.library:
        assert manifest["versions"].get(fw.library) == registry.installed(fw.library), (
            f"{name}: the manifest's versions {manifest['versions']} lack its library "
            f"{fw.library} {registry.installed(fw.library)}")
    scalars = read_scalars(run_dir)
    env = make_env(1)
    try:
        tags = [metrics.EPISODES, metrics.MEAN_RETURN, metrics.MEAN_LENGTH, metrics.SUCCESS_RATE,
                metrics.STEPS_PER_S, metrics.INSTABILITIES,
                *(metrics.REWARD_TERM + n for n in env.reward_names),
                *(metrics.TERMINATION + n for n in env.termination_names)]
    finally:
        env.close()
    missing = [t for t in tags if t not in scalars]
    assert not missing, f"{name}: TensorBoard lacks {missing} (has {sorted(scalars)})"
    last_step = max(step for step, _ in scalars[metrics.STEPS_PER_S])
    assert last_step == steps, f"{name}: last TensorBoard step {last_step}, summary steps {steps}"
    returns = [v for _, v in scalars[metrics.MEAN_RETURN]]
    assert abs(returns[-1] - summary["mean_return"]) < 1e-4 * max(1.0, abs(returns[-1])), (
        f"{name}: summary mean_return {summary['mean_return']} != last logged {returns[-1]}")
    return outcome


def _observations(n: int = 64) -> torch.Tensor:
    """Real cartpole observations from random actions, plus wide random ones."""
    env = make_env(8)
    try:
        obs, _ = env.reset(seed=0)
        out = [obs]
        gen = torch.Generator().manual_seed(0)
        for _ in range(n // 8 - 1):
            obs, *_ = env.step(torch.rand(8, *env.single_action_space.shape, generator=gen) * 2 - 1)
            out.append(obs)
        real = torch.cat(out).float()
    finally:
        env.close()
    return torch.cat([real, torch.randn(n, real.shape[1], generator=gen) * 3])


def check_policy_roundtrip(name: str, tmp_path: Path, overrides: Sequence[str] = (),
                           normalized: bool = True) -> Policy:
    """The framework gives lab its live agent (`ctx.set_actor`), so that each checkpoint's
    Policy is checked to act as the agent it was saved from, on the env's real observations
    (training fails otherwise); the last checkpoint loads as a Policy that gives the same
    deterministic actions every time it is loaded and called, in [-1, 1]; with `normalized`,
    the normalizer is inside."""
    fw = registry.get_framework(name)
    outcome = train_small(name, tmp_path, 2, [*overrides, SHORT_EPISODE])
    assert outcome.policy_difference is not None, (
        f"{name}: train() never calls ctx.set_actor, so nothing shows that its Policy acts as "
        "the trained agent")
    checkpoint = fw.checkpoints(outcome.run.dir)[-1].path
    obs = _observations()
    actions = []
    for num_envs in (NUM_ENVS, 16):  # the policy must not depend on the env's batch size
        env = make_env(num_envs)
        try:
            policy = load_policy(name, checkpoint, env)
        finally:
            env.close()
        assert isinstance(policy, Policy), f"{name}: load_policy returned {type(policy).__name__}"
        assert not policy.training, f"{name}: load_policy must return the Policy in eval mode"
        with torch.no_grad():
            first, again = policy(obs), policy(obs)
        assert torch.equal(first, again), f"{name}: the Policy is not deterministic"
        assert first.shape == (len(obs), 1), f"{name}: action shape {tuple(first.shape)}"
        assert first.abs().max() <= 1.0, f"{name}: actions outside [-1, 1]"
        actions.append(first)
    diff = (actions[0] - actions[1]).abs().max().item()
    assert diff == 0.0, f"{name}: two loads of {checkpoint.name} differ by {diff:.2e}"
    has_normalizer = not isinstance(policy.normalizer, torch.nn.Identity)
    assert has_normalizer == normalized, (
        f"{name}: Policy normalizer is {type(policy.normalizer).__name__}, but observation "
        f"normalization is {'on' if normalized else 'off'}")
    if normalized:
        with torch.no_grad():
            assert not torch.allclose(policy.normalizer(obs), obs), (
                f"{name}: the Policy's normalizer leaves observations unchanged: not the trained "
                "statistics")
    return policy


def _actions(name: str, checkpoint: Path, obs: torch.Tensor) -> torch.Tensor:
    env = make_env()
    try:
        policy = load_policy(name, checkpoint, env)
    finally:
        env.close()
    with torch.no_grad():
        return policy(obs)


def check_resume(name: str, tmp_path: Path, overrides: Sequence[str] = ()) -> float:
    """`checkpoint="latest"` continues the same run: iterations and steps go on from the
    checkpoint, the new checkpoints land in the same run dir, and 2 + 2 iterations end with the
    policy of 4 in one go (same seed, CPU): optimizer, normalizer, learning rate, episodes in
    flight and random generators all carried over. Returns the largest action difference."""
    fw = registry.get_framework(name)
    sets = [*overrides, SHORT_EPISODE, "agent.save_interval=2"]
    first = train_small(name, tmp_path / "resumed", 2, sets)
    per_iteration = first.summary["steps"] // 2
    second = train_small(name, tmp_path / "resumed", 4, sets, checkpoint=checkpoints.LATEST)
    assert second.run.dir == first.run.dir, f"{name}: resume made a new run dir"
    assert second.summary["iterations"] == 4, (
        f"{name}: resumed run ended at iteration {second.summary['iterations']}, not 4")
    assert second.summary["steps"] == 4 * per_iteration, (
        f"{name}: resumed run counts {second.summary['steps']} steps, not "
        f"{4 * per_iteration} (the step count must continue from the checkpoint)")
    found = [c.iteration for c in fw.checkpoints(first.run.dir)]
    assert found[-1] == 4 and 2 in found, f"{name}: checkpoints at iterations {found}"
    manifest = json.loads((first.run.dir / rundir.MANIFEST).read_text())
    assert manifest.get("resumed_from") == fw.checkpoint_path(first.run.dir, 2).name
    once = train_small(name, tmp_path / "once", 4, sets)
    # Stopped by SIGINT half-way through the fourth rollout (iteration 3, not due for a
    # checkpoint, is saved by the stop), then resumed: the partial rollout is dropped as if it
    # never happened.
    steps_per_env = per_iteration // NUM_ENVS
    with sigint_at_env_step(3 * steps_per_env + steps_per_env // 2):
        stopped = train_small(name, tmp_path / "interrupted", 4, sets)
    assert stopped.summary["state"] == rundir.INTERRUPTED and stopped.summary["iterations"] == 3, (
        f"{name}: a stop in the fourth rollout gave {stopped.summary}")
    after_stop = train_small(name, tmp_path / "interrupted", 4, sets, checkpoint=checkpoints.LATEST)
    obs = _observations()
    unbroken = _actions(name, fw.checkpoint_path(once.run.dir, 4), obs)
    diff = 0.0
    for how, run in (("2 + 2 resumed iterations", second), ("a stop mid-rollout", after_stop)):
        resumed = _actions(name, fw.checkpoint_path(run.run.dir, 4), obs)
        diff = max(diff, (resumed - unbroken).abs().max().item())
        assert diff <= RESUME_TOLERANCE, (
            f"{name}: after {how}, the policy acts differently from 4 iterations in one go (max "
            f"action difference {diff:.2e}): some training state was not carried over")
    return diff


@contextlib.contextmanager
def sigint_at_env_step(n: int) -> Iterator[None]:
    """Sends this process SIGINT during the `n`-th env step from now, as Ctrl-C would."""
    original = LabVecEnv.step
    calls = 0

    def step(self: LabVecEnv, actions: Any) -> Any:
        nonlocal calls
        calls += 1
        if calls == n:
            os.kill(os.getpid(), signal.SIGINT)
        return original(self, actions)

    LabVecEnv.step = step
    try:
        yield
    finally:
        LabVecEnv.step = original


def check_determinism(name: str, tmp_path: Path, overrides: Sequence[str] = (),
                      iterations: int = 2) -> list[float]:
    """The same seed on the CPU gives the same mean returns and policy; another seed other
    ones. Returns the mean returns of seed 0."""
    fw = registry.get_framework(name)
    sets = [*overrides, SHORT_EPISODE]
    outcomes = [train_small(name, tmp_path / label, iterations, sets, seed=seed)
                for label, seed in (("a", 0), ("b", 0), ("c", 1))]
    returns = [[v for _, v in sorted(read_scalars(o.run.dir)[metrics.MEAN_RETURN])]
               for o in outcomes]
    obs = _observations()
    actions = [_actions(name, fw.checkpoints(o.run.dir)[-1].path, obs) for o in outcomes]
    assert returns[0] == returns[1] and torch.equal(actions[0], actions[1]), (
        f"{name}: two runs with seed 0 differ: returns {returns[0]} and {returns[1]}")
    assert returns[0] != returns[2] and not torch.equal(actions[0], actions[2]), (
        f"{name}: seeds 0 and 1 gave the same returns {returns[0]}: the seed is not used")
    return returns[0]


def check_export(name: str, tmp_path: Path, overrides: Sequence[str] = ()) -> float:
    """The Policy exports to ONNX and matches torch within 1e-5; returns the max difference."""
    from labcli.runs.export import Format, export

    fw = registry.get_framework(name)
    outcome = train_small(name, tmp_path, 1, [*overrides, SHORT_EPISODE])
    result = export(Format.onnx, run_dir=outcome.run.dir)
    assert result.path.is_file(), f"{name}: no {result.path}"
    import onnxruntime as ort

    env = make_env()
    try:
        policy = load_policy(name, fw.checkpoints(outcome.run.dir)[-1].path, env)
    finally:
        env.close()
    obs = _observations()
    with torch.no_grad():
        expected = policy(obs).numpy()
    session = ort.InferenceSession(str(result.path), providers=["CPUExecutionProvider"])
    got = session.run(None, {"obs": obs.numpy()})[0]
    diff = float(np.max(np.abs(got - expected)))
    assert result.max_abs_diff < EXPORT_TOLERANCE and diff < EXPORT_TOLERANCE, (
        f"{name}: ONNX differs from torch by {max(diff, result.max_abs_diff):.2e}")
    return diff


def check_training_improves(name: str, tmp_path: Path, overrides: Sequence[str] = (),
                            iterations: int = 25, num_envs: int | None = None, seed: int = 0,
                            factor: float = 1.5) -> tuple[float, float]:
    """A short cartpole run with the task's defaults for the framework, env count included
    (plus `overrides`, not the tiny ones: a 16-unit agent learns little in 25 iterations), must
    raise the mean episode return. Returns start negative (a falling pole costs more than
    staying alive earns), so the test is on the gain, not a ratio: the mean of the last three
    logged values must exceed the mean of the first three by (`factor` - 1) x the first's
    magnitude (at least 1). Returns (first, last). Measured on 2 cores, seeds 0-2: each built-in
    framework gains 2.9-5.8x that. At 16 envs the gain was chance (-0.1x to 4.1x, under 1x in
    three runs of nine), and a run's numbers differ between CPUs: a seed that passed on one CPU
    failed on another."""
    outcome = train_small(name, tmp_path, iterations, overrides, num_envs=num_envs, seed=seed)
    returns = [v for _, v in sorted(read_scalars(outcome.run.dir)[metrics.MEAN_RETURN])]
    assert len(returns) >= 6, f"{name}: only {len(returns)} mean returns logged"
    first, last = float(np.mean(returns[:3])), float(np.mean(returns[-3:]))
    needed = (factor - 1) * max(abs(first), 1.0)
    assert last - first > needed, (
        f"{name}: mean return went from {first:.2f} to {last:.2f} in {iterations} iterations "
        f"of {num_envs} envs (needs a gain > {needed:.2f})")
    return first, last


def check_framework(name: str, tmp_path: Path, small_overrides: Sequence[str] = (),
                    probe: Probe | None = None, normalized: bool = True,
                    improve_overrides: Sequence[str] | None = ()) -> None:
    """Every check above, each in its own subdirectory of `tmp_path`. `small_overrides` make
    the agent tiny for the API checks; `improve_overrides` (None: skip) go to the learning
    check on top of the task's defaults."""
    check_adapter(name, probe)
    check_training_outputs(name, tmp_path / "outputs", small_overrides)
    check_policy_roundtrip(name, tmp_path / "policy", small_overrides, normalized)
    check_resume(name, tmp_path / "resume", small_overrides)
    check_determinism(name, tmp_path / "determinism", small_overrides)
    check_export(name, tmp_path / "export", small_overrides)
    if improve_overrides is not None:
        check_training_improves(name, tmp_path / "improve", improve_overrides)


# Tasks -------------------------------------------------------------------------------------------
# A task plugin's own tests call `check_task("mytask")` (with `overrides` that make it small). Each
# check builds the real task on the cpu backend and fails with an AssertionError that names the
# task and what it got wrong.

TASK_ENVS = 4
TASK_STEPS = 16


def task_env(task: str, overrides: Sequence[str] = (), num_envs: int = TASK_ENVS,
             seed: int = 0) -> LabVecEnv:
    """Task `task`'s env on the cpu backend, its config the task's defaults under `overrides`
    ("env.KEY=VALUE", as `--set` takes them)."""
    spec = registry.get_task(task)
    layers = [config.parse_set(overrides)["env"], {"num_envs": num_envs}]
    return make.make_env(spec, config.build(spec.config_class, "env", layers), backend="cpu",
                         device="cpu", seed=seed)


def _task_actions(env: LabVecEnv, steps: int, seed: int = 0) -> list[torch.Tensor]:
    """`steps` batches of actions drawn uniformly within the action space (or ±1 where it is
    unbounded), the same for the same seed."""
    space = env.single_action_space
    low = torch.as_tensor(np.maximum(space.low, -1.0), dtype=torch.float32)
    high = torch.as_tensor(np.minimum(space.high, 1.0), dtype=torch.float32)
    draw = torch.Generator().manual_seed(seed)
    return [low + (high - low) * torch.rand((env.num_envs, *space.shape), generator=draw)
            for _ in range(steps)]


def _rollout(env: LabVecEnv, actions: list[torch.Tensor]) -> list[tuple[torch.Tensor, ...]]:
    return [tuple(t.clone() for t in env.step(a)[:4]) for a in actions]


def _assert_task_values_finite(task: str, env: LabVecEnv, when: str) -> None:
    """The task's own observations and reward terms, before the env puts zeros in place of a
    non-finite value (which keeps training alive but hides the task's bug)."""
    raw = env.task.observations()
    bad = torch.isfinite(raw).logical_not().any(dim=0).nonzero().flatten().tolist()
    assert not bad, (f"task {task!r}: its observations {[env.observation_names[i] for i in bad]} "
                     f"{when} are not finite")
    for name, value in env.task.reward_terms().items():
        assert torch.isfinite(value).all(), f"task {task!r}: its reward term {name!r} {when} is " \
                                            "not finite"


def check_task_outputs(task: str, overrides: Sequence[str] = ()) -> None:
    """Observations, rewards and episode flags of a reset and of steps under random actions:
    their shapes and dtypes, finite values (the task's own, before the env's guard), one name
    per observation column, one command rule per action."""
    env = task_env(task, overrides)
    try:
        n, width = env.num_envs, len(env.observation_names)
        assert env.single_observation_space.shape == (width,), (
            f"task {task!r}: observation space {env.single_observation_space.shape}, but "
            f"{width} observation names")
        assert len(env.describe()["actions"]) == env.single_action_space.shape[0], (
            f"task {task!r}: {len(env.describe()['actions'])} action commands for an action "
            f"space of {env.single_action_space.shape}")
        obs, _ = env.reset(seed=0)
        assert obs.shape == (n, width) and obs.dtype == torch.float32, (
            f"task {task!r}: reset's observations are {tuple(obs.shape)} {obs.dtype}, not "
            f"({n}, {width}) float32")
        _assert_task_values_finite(task, env, "at reset")
        for step, action in enumerate(_task_actions(env, TASK_STEPS), start=1):
            obs, reward, terminated, truncated, _ = env.step(action)
            assert obs.shape == (n, width), (
                f"task {task!r}: step {step}'s observations are {tuple(obs.shape)}")
            assert reward.shape == (n,) and torch.isfinite(reward).all(), (
                f"task {task!r}: step {step}'s rewards are {tuple(reward.shape)}, or not finite")
            for name, flag in (("terminated", terminated), ("truncated", truncated)):
                assert flag.shape == (n,) and flag.dtype == torch.bool, (
                    f"task {task!r}: step {step}'s {name} is {tuple(flag.shape)} {flag.dtype}, "
                    f"not ({n},) bool")
            _assert_task_values_finite(task, env, f"after step {step}")
    finally:
        env.close()


def check_task_episodes(task: str, overrides: Sequence[str] = ()) -> None:
    """Episodes shortened to a few steps end in every env, and their figures are counted: the
    number of episodes and a success rate within [0, 1]."""
    probe = task_env(task, overrides, num_envs=1)
    episode = 4 * probe.step_dt
    probe.close()
    env = task_env(task, [*overrides, f"env.episode_length_s={episode!r}"])
    try:
        env.reset(seed=0)
        ended = torch.zeros(env.num_envs, dtype=torch.bool)
        for _, _, terminated, truncated in _rollout(env, _task_actions(env, 6)):
            ended |= terminated | truncated
        stats = env.pop_stats()
        stuck = ended.logical_not().nonzero().flatten().tolist()
        assert not stuck, (f"task {task!r}: envs {stuck} did not end within 6 steps of 4-step "
                           "episodes")
        assert stats.get(metrics.EPISODES, 0) >= env.num_envs, (
            f"task {task!r}: {stats.get(metrics.EPISODES, 0)} episodes counted of "
            f"{env.num_envs} or more that ended")
        assert 0.0 <= stats[metrics.SUCCESS_RATE] <= 1.0, (
            f"task {task!r}: success rate {stats[metrics.SUCCESS_RATE]}")
    finally:
        env.close()


def check_task_determinism(task: str, overrides: Sequence[str] = ()) -> None:
    """Two envs of one seed under the same actions give the same outputs, bit for bit."""
    runs = []
    for _ in range(2):
        env = task_env(task, overrides, seed=3)
        try:
            env.reset(seed=3)
            runs.append(_rollout(env, _task_actions(env, TASK_STEPS)))
        finally:
            env.close()
    _assert_same_outputs(task, "two envs of one seed", *runs)


def check_task_resume(task: str, overrides: Sequence[str] = ()) -> None:
    """An env of another seed, resumed from a first one's state, goes on as the first does:
    everything the task carries from step to step is in `Task.state`. Observation noise is
    off: a resumed env draws its first observations' noise anew."""
    if "observation_noise" in registry.get_task(task).config_class.model_fields:
        overrides = ["env.observation_noise=false", *overrides]
    env, twin = task_env(task, overrides, seed=1), task_env(task, overrides, seed=2)
    try:
        env.reset(seed=1)
        actions = _task_actions(env, 2 * TASK_STEPS, seed=5)
        _rollout(env, actions[:TASK_STEPS])
        twin.resume_from(env.get_state())
        twin.reset()
        _assert_same_outputs(task, "a resumed env", _rollout(env, actions[TASK_STEPS:]),
                             _rollout(twin, actions[TASK_STEPS:]))
    finally:
        env.close(), twin.close()


def _assert_same_outputs(task: str, what: str, expected: list, got: list) -> None:
    names = ("observations", "rewards", "terminated", "truncated")
    for step, (want, have) in enumerate(zip(expected, got, strict=True), start=1):
        for name, a, b in zip(names, want, have, strict=True):
            assert torch.equal(a, b), (f"task {task!r}: {what} differs at step {step} in its "
                                       f"{name}")


def check_task(task: str, overrides: Sequence[str] = ()) -> None:
    """Every task check above: what a task plugin must pass to train with every framework."""
    check_task_outputs(task, overrides)
    check_task_episodes(task, overrides)
    check_task_determinism(task, overrides)
    check_task_resume(task, overrides)
