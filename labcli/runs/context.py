"""The TrainContext a framework's `train` is handed: lab's side of the contract in
labcli/plugins/framework.py. It logs the figures every framework shares, drives the progress
bar, writes checkpoints atomically with the env state beside them, checks that each one loads
as a Policy acting like the live agent, keeps the last good state of a diverging run, and turns
SIGINT/SIGTERM into a stop at the next env step (`StopAtRequest`)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import torch
from torch import nn
from torch.utils.tensorboard import SummaryWriter

from labcli.envs import metrics, mjwarnings
from labcli.errors import LabError, TrainingDiverged
from labcli.plugins.config import AgentConfig
from labcli.plugins.framework import Actor, Checkpoint, Framework, Save, StopTraining, TrainContext
from labcli.runs import checkpoints, distributed, interrupt, loading, snapshot
from labcli.runs.lastgood import LastGood
from labcli.runs.progress import TrainProgress
from labcli.runs.ranks import SINGLE, Ranks

NONFINITE_NETWORKS = "its update left non-finite values (NaN or inf) in the agent's networks"
DIVERGED_HINT = ("lower agent.learning_rate (or raise its clipping) and resume from the last good "
                 "checkpoint with --checkpoint")
# How far a checkpoint's Policy may act from the live agent it was saved from. Both run the same
# float32 operations, at most regrouped (a normalizer's std + eps squared, then rooted): the
# built-ins are 6e-8 apart or less; a constant actor or a normalizer handed the std as the
# variance were 0.22 and 0.04 apart after two tiny cartpole iterations.
POLICY_TOLERANCE = 1e-4
# on_iteration(iteration, steps, figures) -> stop?
IterationHook = Callable[[int, int, Mapping[str, float]], bool]


class StopAtRequest(gym.vector.VectorWrapper):
    """The innermost wrapper while training: once a stop is requested, the next step raises
    StopTraining, out of whatever loop the library runs. Everything else passes through."""

    def __init__(self, env: gym.vector.VectorEnv, stop: interrupt.StopRequest):
        super().__init__(env)
        self.stop = stop
        # An env that waits on other processes (the cpu backend's shards) gives up on them a
        # while after a stop, rather than waiting forever on one that cannot finish.
        if hasattr(env.unwrapped, "interrupted"):
            env.unwrapped.interrupted = lambda: stop.requested

    def __getattr__(self, name: str) -> Any:
        if name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)

    def step(self, actions: Any):
        if self.stop.requested:
            raise StopTraining
        return self.env.step(actions)


@dataclass
class RunContext(TrainContext):
    """lab's TrainContext: the one a framework's `train` is handed (see its docstrings in
    labcli/plugins/framework.py for the contract)."""

    cfg: AgentConfig
    env: Any
    framework: Framework
    run_dir: Path
    seed: int
    device: str
    progress: TrainProgress
    writer: SummaryWriter
    resume: Checkpoint | None = None
    resume_state: dict[str, Any] | None = None
    stop: interrupt.StopRequest = field(default_factory=interrupt.StopRequest)
    mujoco_warnings: mjwarnings.WarningCounter = field(default_factory=mjwarnings.WarningCounter)
    changed: frozenset[str] = frozenset()
    # Told each iteration's figures (a sweep reports them to its scheduler); True stops the run
    # as a signal would: checkpointed, state 'interrupted', resumable.
    on_iteration: IterationHook | None = None
    # This process's place in a data-parallel run: only rank 0 writes (TensorBoard, progress,
    # checkpoints, the hook above); every rank logs the figures of all ranks' envs.
    ranks: Ranks = SINGLE
    update_threads: int = 1
    iteration: int = 0
    steps: int = 0
    last_stats: dict[str, float] = field(default_factory=dict)
    _since_save: EpisodesSinceSave = field(default_factory=lambda: EpisodesSinceSave())
    saved_iteration: int = -1
    saved_steps: int = 0
    # The env and random generators at the end of the last iteration, saved with its checkpoint.
    _boundary: dict[str, Any] | None = None
    _told_mujoco_warnings: bool = False
    _told_overflows: bool = False
    # This run's totals of what the physics warned of, for the line at its end.
    _overflow_totals: dict[str, float] = field(default_factory=dict)
    _mujoco_warning_total: int = 0
    _networks: list[nn.Module] = field(default_factory=list)
    _actor: Actor | None = None
    # The largest action difference between a checkpoint's Policy and the live agent so far;
    # None while the framework gave no actor.
    policy_difference: float | None = None
    last_good: LastGood = field(init=False)
    _clock: tuple[float, int] = (0.0, 0)

    def __post_init__(self) -> None:
        if self.resume is not None:
            self.iteration = self.saved_iteration = self.resume.iteration
        if self.resume_state is not None:
            self.steps = self.saved_steps = self.resume_state["steps"]
        self._clock = (time.perf_counter(), self.steps)
        self.last_good = LastGood(self.run_dir, self.framework.spec)
        if self.ranks.writer:
            # Left by a killed run: not this run's, never to be committed or published.
            self.last_good.discard()
            checkpoints.discard_staging(self.run_dir)

    @property
    def rank(self) -> int:
        return self.ranks.rank

    @property
    def world_size(self) -> int:
        return self.ranks.world_size

    @property
    def stop_requested(self) -> bool:
        return self.stop.requested

    def restore_rng(self) -> None:
        # Building the agent draws random weights: restored after it, a resumed run samples
        # what an unbroken one would.
        if self.resume_state is not None:
            snapshot.set_rng_state(self.resume_state["rng"])

    def end_iteration(self, iteration: int, steps: int, save: Save,
                      scalars: Mapping[str, float] | None = None, *,
                      last_good: Save | None = None) -> bool:
        steps *= self.ranks.world_size  # each rank counts its own envs' steps
        now = time.perf_counter()
        t0, s0 = self._clock
        steps_per_s = (steps - s0) / max(now - t0, 1e-9)
        self._clock = (now, steps)
        self.iteration, self.steps = iteration, steps
        stats = self.env.pop_stats(self._summed if self.ranks.active else None)
        if stats:
            self._since_save.add(stats)
        if stats.get(metrics.EPISODES):
            # The last figures of ended episodes, for the progress line and the summary: an
            # iteration in which none ended (its buffers' overflows alone) keeps them.
            self.last_stats = stats
        bad = stats.get(metrics.NONFINITE_ACTIONS, 0)
        if bad:  # the candidate, which acted in this rollout, is bad
            raise self._diverged(iteration, "the policy emitted non-finite actions (NaN or inf) "
                                 f"in {bad:.0f} env steps", candidate_proven=False)
        if not self.networks_finite():  # the candidate acted well; this update broke it
            raise self._diverged(iteration, NONFINITE_NETWORKS, candidate_proven=True)
        self._boundary = {"env": self.env.get_state(), "rng": snapshot.rng_state(),
                          "iteration": iteration, "steps": steps}
        if self.ranks.writer:
            self.last_good.promote()
            self.last_good.keep(iteration, self._boundary, last_good or save)
            self._note_overflows(stats)
            figures = {**stats, metrics.STEPS_PER_S: steps_per_s,
                       metrics.MUJOCO_WARNINGS: self._pop_mujoco_warnings(), **(scalars or {})}
            for tag, value in figures.items():
                self.writer.add_scalar(tag, value, steps)
            self.progress.update(iteration, steps_per_s,
                                 self.last_stats.get(metrics.MEAN_RETURN),
                                 self.last_stats.get(metrics.SUCCESS_RATE),
                                 self.last_stats.get(metrics.TERRAIN_LEVEL), steps=steps)
            if self.on_iteration is not None and self.on_iteration(iteration, steps, figures):
                self.stop.request()
        stopping = self.stop_requested
        if self.ranks.active:
            # Every rank decides on the agreed signal alone: one that arrives after the
            # agreement counts at the next, else this rank would leave the others mid-update.
            agreed = distributed.agreed_stop(self.stop.signum, self.device)
            stopping = agreed is not None
            if stopping:
                self.stop.request(agreed)
        stopping = stopping or iteration >= self.cfg.max_iterations
        if stopping or iteration % self.cfg.save_interval == 0:
            self.save(save)
        return stopping

    def _summed(self, totals: torch.Tensor) -> torch.Tensor:
        return distributed.summed(totals, self.device)

    def watch(self, *networks: nn.Module) -> None:
        # Checked after each update, so that a diverged update stops training with a clear
        # message, not a library's traceback later.
        self._networks.extend(networks)

    def set_actor(self, actor: Actor) -> None:
        self._actor = actor

    def networks_finite(self) -> bool:
        return all(_finite(module) for module in self._networks)

    def failed_on_networks(self, exc: Exception) -> TrainingDiverged:
        """For a library that failed in an update on the NaN it produced: the candidate is
        proven if it acted finitely in the rollout before."""
        acted_finitely = not self.env.pop_stats().get(metrics.NONFINITE_ACTIONS, 0)
        error = self._diverged(self.iteration + 1, NONFINITE_NETWORKS, acted_finitely)
        error.message += f" ({self.framework.name} failed on them: {type(exc).__name__}: {exc})"
        return error

    def _diverged(self, iteration: int, what: str, candidate_proven: bool) -> TrainingDiverged:
        if self.ranks.writer:
            self.last_good.commit(candidate_proven)
        return TrainingDiverged(f"iteration {iteration}: {what}; training stopped. "
                                f"{self._last_good()}", DIVERGED_HINT)

    def _pop_mujoco_warnings(self) -> int:
        count = self.mujoco_warnings.pop()
        self._mujoco_warning_total += count
        if count and not self._told_mujoco_warnings:
            self._told_mujoco_warnings = True
            self.progress.console.print(
                f"note: MuJoCo warns '{self.mujoco_warnings.first}'; the envs concerned are "
                f"reset and counted ({metrics.INSTABILITIES}), and further warnings in "
                f"{metrics.MUJOCO_WARNINGS}", highlight=False, soft_wrap=True)
        return count

    def _note_overflows(self, stats: Mapping[str, float]) -> None:
        overflows = sorted(k.removeprefix(metrics.OVERFLOW) for k in stats
                           if k.startswith(metrics.OVERFLOW))
        for name in overflows:
            self._overflow_totals[name] = (self._overflow_totals.get(name, 0.0)
                                           + stats[metrics.OVERFLOW + name])
        # A solver out of iterations kept its last iterate (counted only); a buffer that
        # overflowed lost contacts or constraints (those envs are reset).
        buffers = [k for k in overflows if "ITERATIONS" not in k]
        if buffers and not self._told_overflows:
            self._told_overflows = True
            self.progress.console.print(
                f"note: MuJoCo Warp's {', '.join(buffers)} buffer overflowed; the envs "
                f"concerned are reset and counted ({metrics.OVERFLOW}<buffer>): raise "
                "env.nconmax or env.njmax", highlight=False, soft_wrap=True)

    def physics_summary(self) -> str | None:
        """One line for the end of training: what the physics warned of this run (None if
        nothing)."""
        return physics_summary(self._overflow_totals, self._mujoco_warning_total,
                               self.mujoco_warnings.first)

    def save(self, save: Save) -> None:
        """A complete checkpoint set of the current iteration (labcli/runs/checkpoints.py), with
        the env and generator state of that iteration's end. A policy that acts with NaN, or
        otherwise than the live agent, is never published: it stops training instead."""
        if self.saved_iteration == self.iteration:
            return
        boundary = self._boundary
        if boundary is not None and boundary["iteration"] != self.iteration:
            boundary = None
        if self.ranks.active:
            boundary = self._with_every_rank(boundary)
        if self.ranks.writer:
            state = snapshot.writer(self.iteration, boundary) if boundary is not None else None
            checkpoints.write(self.run_dir, self.framework.spec, self.iteration, save, state,
                              check=self._check_policy, figures=self._since_save.pop())
        self.saved_iteration, self.saved_steps = self.iteration, self.steps

    def _with_every_rank(self, boundary: dict[str, Any] | None) -> dict[str, Any] | None:
        """Rank 0's boundary with the other ranks' episodes and generators beside it (on rank
        0; every rank takes part): a resume goes on with each rank's own."""
        mine = None
        if boundary is not None:
            env = boundary["env"]
            mine = {"env": None if env is None else {k: v.cpu() for k, v in env.items()},
                    "rng": boundary["rng"]}
        parts = distributed.gather_to_writer(self.ranks, mine)
        if parts is None or boundary is None or any(part is None for part in parts):
            return boundary
        return {**boundary, "ranks": parts[1:]}

    def _check_policy(self, checkpoint: Path) -> None:
        # Loading builds networks, which draws random weights (SB3's even reseeds every
        # generator): the run must go on with the numbers it would have drawn without the check.
        rng = snapshot.rng_state()
        obs = self.env.observations()
        try:
            # Policies load onto the CPU (portable checkpoints); the env may be on a GPU.
            policy = loading.load(self.framework, checkpoint, self.env, self.cfg).to(
                self.env.device)
            with torch.no_grad():
                actions = policy(obs)
                live = None if self._actor is None else self._actor(obs)
        finally:
            snapshot.set_rng_state(rng)
        if not bool(torch.isfinite(actions).all()):
            raise self._diverged(self.iteration, "the policy's actions are not finite (NaN or "
                                 "inf) after this iteration's update", candidate_proven=False)
        if live is not None:
            self._compare(checkpoint, actions,
                          torch.as_tensor(live).to(actions).clamp(-policy.clip, policy.clip))

    def _compare(self, checkpoint: Path, actions: torch.Tensor, live: torch.Tensor) -> None:
        """The Policy of `checkpoint` must act as the agent that was saved in it."""
        if live.shape != actions.shape:
            raise LabError(f"framework '{self.framework.name}': its live agent gives actions of "
                           f"shape {tuple(live.shape)}, its Policy {tuple(actions.shape)}",
                           "a bug in the framework plugin: report it to its authors")
        difference = (actions - live).abs().max().item()
        self.policy_difference = max(self.policy_difference or 0.0, difference)
        if not difference <= POLICY_TOLERANCE:
            raise LabError(f"framework '{self.framework.name}': the Policy loaded from "
                           f"{checkpoint.name} acts up to {difference:.2g} away from the agent "
                           f"it was saved from (allowed: {POLICY_TOLERANCE:g}); playing or "
                           "exporting it would not run what was trained",
                           "a bug in the framework plugin's load_policy: report it to its "
                           "authors")

    def _last_good(self) -> str:
        found = self.framework.spec.checkpoints(self.run_dir)
        if not found:
            return "No checkpoint was written before it."
        return f"The last good checkpoint is {found[-1].path.name}."


class EpisodesSinceSave:
    """The episodes that ended since the last checkpoint: their count, mean success and mean
    return, which the next checkpoint records (`--checkpoint best` ranks by them). Over the
    whole interval, not the last iteration's few episodes."""

    def __init__(self) -> None:
        self.count = self.successes = self.returns = 0.0

    def add(self, stats: Mapping[str, float]) -> None:
        n = stats.get(metrics.EPISODES, 0.0)
        self.count += n
        self.successes += n * stats.get(metrics.SUCCESS_RATE, 0.0)
        self.returns += n * stats.get(metrics.MEAN_RETURN, 0.0)

    def pop(self) -> dict[str, float] | None:
        figures = None
        if self.count > 0 and math.isfinite(self.returns):
            figures = {checkpoints.SUCCESS: self.successes / self.count,
                       checkpoints.RETURN: self.returns / self.count,
                       checkpoints.EPISODES: self.count}
        self.count = self.successes = self.returns = 0.0
        return figures


def _finite(module: nn.Module) -> bool:
    # One read-back for the whole module, not one per tensor (a GPU sync each).
    flags = [torch.isfinite(t).all() for t in module.state_dict().values()
             if t.is_floating_point()]
    return not flags or bool(torch.stack(flags).all())


def physics_summary(overflows: Mapping[str, float], mujoco_warnings: int,
                    first_warning: str | None) -> str | None:
    """How often the physics warned in a run, by what, with the setting that would quiet each
    (the counts per iteration are in TensorBoard); None if it never did."""
    parts = []
    for name, count in sorted(overflows.items()):
        if "ITERATIONS" in name:
            setting = "env.ls_iterations" if name.startswith("LS_") else "env.solver_iterations"
            parts.append(f"MuJoCo Warp's {name} limit was reached in {count:,.0f} env steps "
                         f"(its last iterate kept; raise {setting})")
        else:
            parts.append(f"MuJoCo Warp's {name} buffer overflowed in {count:,.0f} env steps "
                         "(those envs reset; raise env.nconmax or env.njmax)")
    if mujoco_warnings:
        parts.append(f"MuJoCo warned {mujoco_warnings:,} times ('{first_warning}'; those envs "
                     "reset)")
    if not parts:
        return None
    tags = [f"{metrics.OVERFLOW}<name>"] * bool(overflows) + [metrics.MUJOCO_WARNINGS] * bool(
        mujoco_warnings)
    return f"physics: {'; '.join(parts)}; per iteration in TensorBoard ({', '.join(tags)})"
