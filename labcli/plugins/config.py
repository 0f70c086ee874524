"""`AgentConfig`: the settings every framework has, which a framework plugin's pydantic config
subclasses with its library's hyperparameters. Kept apart from the spec that names it, so that
loading plugins imports no pydantic."""

from __future__ import annotations

from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field

from labcli.errors import LabError


class AgentConfig(BaseModel):
    """Settings every framework has; a plugin subclasses it with its library's hyperparameters."""

    # NaN and inf are never meant: they would only surface later as a diverged run.
    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)
    # The keys a resume (`lab train --checkpoint`) may change; the framework applies them over
    # what the checkpoint restores (`TrainContext.changed`). A subclass adds its own, e.g. the
    # learning rate; the network's shape, the rollout's length, the seed can never change.
    resumable: ClassVar[frozenset[str]] = frozenset({"max_iterations", "save_interval", "tf32"})

    max_iterations: int = Field(100, gt=0, description="rollout + update cycles in total")
    save_interval: int = Field(50, gt=0, description="iterations between checkpoints")
    seed: int = Field(0, ge=0, lt=2**32, description="seeds the env, torch, NumPy and Python")
    # Off unless a task's defaults measured it harmless: panda-lift's three seeds in TF32
    # carried the cube in 46-67% of training's episodes after 1,000 iterations, against 64-83%
    # in float32, and its learning phase was no shorter (docs/benchmarks.md).
    tf32: bool = Field(False, description="on a GPU, float32 matrix products in TF32 (a 10-bit "
                       "mantissa; Ampere and later), as mjlab trains; false: full float32; the "
                       "CPU ignores it")

    def check(self, num_envs: int) -> None:
        """Refuse settings that cannot work with `num_envs` envs, before anything is built: a
        LabError naming the key (more mini-batches than samples, say). The default checks
        nothing."""

    def check_env(self, env: Any) -> None:
        """Refuse settings the built env cannot serve (a symmetry its task does not declare),
        before a run dir exists: a LabError. The default checks nothing."""

    def memory(self, num_envs: int, observations: int, actions: int) -> dict[str, int]:
        """Bytes the learner will allocate, by the setting that decides them
        ({"agent.n_steps": ..., "agent.net_arch": ...}): lab refuses a run that cannot fit in
        the memory left, naming the largest. `mlp_bytes` and `FLOAT` help. Default: none."""
        return {}


FLOAT = 4  # bytes of a float32


def mlp_bytes(sizes: list[int]) -> int:
    """An MLP's parameters, with their gradients and Adam's two moments: 4 floats each."""
    return 4 * FLOAT * sum(a * b + b for a, b in zip(sizes, sizes[1:], strict=False))


def too_many_batches(key: str, batches: int, samples: int) -> LabError:
    return LabError(f"{key}={batches} splits {samples:,} samples per iteration into more "
                    "mini-batches than samples", f"use at most {samples:,}, or more envs or steps")


# Off-policy learners (SAC, TD3) ------------------------------------------------------------------

def check_replay_size(key: str, transitions: int, num_envs: int) -> None:
    """A replay memory of `transitions` (over all envs) must hold one step of every env."""
    if transitions < num_envs:
        raise LabError(f"{key}={transitions:,} holds less than one step of {num_envs:,} envs",
                       f"use at least {num_envs:,}")


def replay_bytes(transitions: int, observations: int, actions: int, scalars: int) -> int:
    """A replay memory: observations and next observations, actions and `scalars` more numbers
    (reward, done, ...) a transition, as floats."""
    return transitions * (2 * observations + actions + scalars) * FLOAT


def twin_critic_bytes(observations: int, hidden: list[int], actions: int,
                      actor_outputs: int) -> int:
    """An actor of `actor_outputs` numbers per action and a copy of it, two Q critics and their
    targets, as `mlp_bytes` counts each (a target has no gradients: a bound from above)."""
    critic = mlp_bytes([observations + actions, *hidden, 1])
    return 2 * mlp_bytes([observations, *hidden, actor_outputs * actions]) + 4 * critic
