"""The env configs: `TaskConfig`, which every task's config subclasses, and `GymConfig`, the
config of `gym:<id>` tasks. pydantic models, kept apart from the specs that name them so that
loading plugins imports no pydantic."""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import annotated_types
from pydantic import BaseModel, ConfigDict, Field, model_validator

# A velocity this large (rad/s or m/s; or NaN) means the integrator diverged: such envs are
# reset. A task may set a lower limit (`unstable_velocity`).
UNSTABLE_VELOCITY = 1e6


class TaskConfig(BaseModel):
    """Settings every task has; a task subclasses it to add its own (reset ranges, bounds...)."""

    # NaN and inf are never meant: they would only surface later as a diverged run.
    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)
    # The keys a resume may change: how many envs step (they start new episodes) and how; not
    # the task itself (rewards, episodes, physics), which the checkpoint was trained on.
    resumable: ClassVar[frozenset[str]] = frozenset({"num_envs", "threads", "cuda_graph",
                                                     "compile", "stagger_episodes"})
    # What `lab play` sets unless the user sets it (e.g. observation noise off).
    play_overrides: ClassVar[dict[str, Any]] = {}
    # Dotted keys `lab play --set` may change besides those: conditions to test a policy under
    # (a motor's latency).
    play_settable: ClassVar[frozenset[str]] = frozenset()

    # The upper bounds are far beyond any use; past them a typo would exhaust memory or overflow
    # the step count instead of failing at once.
    num_envs: int = Field(64, gt=0, le=2**20, description="parallel environments")
    episode_length_s: float = Field(5.0, gt=0, le=1e6, description="time-out, in seconds")
    decimation: int = Field(2, gt=0, le=1000, description="physics steps per env step")
    # Isaac Lab's and mjlab's rsl_rl training (`init_at_random_ep_len`). Without it every env
    # starts together, and where few episodes end early (an arm's) they time out together for
    # the whole run: each rollout then holds one stretch of the episode only.
    stagger_episodes: bool = Field(False, description="training: each env's first episode "
                                   "starts at a random step before the time-out (drawn from "
                                   "the env's seed), so that the envs' episodes do not run in "
                                   "lockstep; `lab play` and a resumed run's saved episodes "
                                   "never are")
    unstable_velocity: float = Field(UNSTABLE_VELOCITY, gt=0, description="a joint or the base "
                                     "faster than this (rad/s or m/s) ends the episode as "
                                     "diverged, as a non-finite state does: a runaway of the "
                                     "physics, not a state to learn from")
    sim_dt: float | None = Field(None, gt=0, description="physics step; None keeps the MJCF's")
    solver_iterations: int | None = Field(None, gt=0, le=1000, description="the constraint "
                                          "solver's iterations; None keeps the MJCF's")
    ls_iterations: int | None = Field(None, gt=0, le=1000, description="its line search's "
                                      "iterations; None keeps the MJCF's")
    # Menagerie's quadrupeds use elliptic cones (mjlab's Go1 too, at impratio 10): exact, and on
    # the CPU a Go1 step takes 2.3x as long as with pyramidal ones.
    cone: Literal["pyramidal", "elliptic"] | None = Field(
        None, description="friction cones; None keeps the MJCF's")
    impratio: float | None = Field(None, gt=0, le=1e4, description="the ratio of frictional to "
                                   "normal constraint impedance; None keeps the MJCF's")
    # Menagerie's Go1 and Go2 name none, so MuJoCo's Euler integrates their PD servos' damping
    # explicitly; mjlab steps every robot with implicitfast. Both backends have these three.
    integrator: Literal["euler", "implicitfast", "rk4"] | None = Field(
        None, description="the integrator; None keeps the MJCF's")
    # MuJoCo's soft contacts let a held object creep: a cube held still in a Panda's fingers
    # slides 6-16 mm down them in 5 s (tests/test_manipulation.py). Both backends have it.
    noslip_iterations: int | None = Field(None, ge=0, le=1000, description="iterations of "
                                          "MuJoCo's noslip solver after the main one, which "
                                          "removes that creep (0: off); None keeps the MJCF's")
    action_scale: float = Field(1.0, description="policy action in [-1, 1] times this is ctrl")
    clip_actions: float = Field(1.0, gt=0, description="actions are clipped to ±this before "
                                "the task turns them into controls: the env's action space")
    reward_weights: dict[str, float] = Field(default_factory=dict)
    threads: int | None = Field(None, gt=0, le=4096, description="cpu backend: threads that "
                                "step the physics (None: the cores this process may use)")
    nconmax: int | None = Field(None, gt=0, le=2**16, description="warp backend: contacts "
                                "per env its buffers hold (None: MuJoCo Warp's estimate)")
    njmax: int | None = Field(None, gt=0, le=2**16, description="warp backend: constraint rows "
                              "per env (None: MuJoCo Warp's estimate)")
    cuda_graph: bool = Field(True, description="on a GPU, replay each env step as one CUDA graph "
                             "(false: step eagerly, for debugging a task)")
    compile: bool = Field(False, description="cpu backend: trace each env step once and compile "
                          "its torch code (TorchInductor; needs a C++ compiler; the first step "
                          "compiles, seconds to minutes, then cached): faster on many cores")

    @model_validator(mode="after")
    def _within_bounds(self) -> TaskConfig:
        """These settings' bounds hold in a task that declares one again with a default of its
        own (`nconmax: int | None = 16`), which replaces the field and its bounds."""
        for name, field in TaskConfig.model_fields.items():
            value = getattr(self, name)
            if not isinstance(value, int | float) or isinstance(value, bool):
                continue
            for bound in field.metadata:
                for kind, holds in _BOUNDS.items():
                    limit = getattr(bound, kind, None)
                    if isinstance(bound, annotated_types.BaseMetadata) and limit is not None \
                            and not holds(value, limit):
                        raise ValueError(f"{name} is {value}: it must be {_SAYS[kind]} {limit}")
        return self

    def weights(self, step_dt: float) -> dict[str, float]:
        """Each reward term's weight per env step of `step_dt` s, by name."""
        return dict(self.reward_weights)


_BOUNDS = {"gt": lambda v, b: v > b, "ge": lambda v, b: v >= b, "lt": lambda v, b: v < b,
           "le": lambda v, b: v <= b}
_SAYS = {"gt": "above", "ge": "at least", "lt": "below", "le": "at most"}


class GymConfig(BaseModel):
    """The env settings of a gymnasium task (`--set env.KEY=VALUE`)."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)
    resumable: ClassVar[frozenset[str]] = frozenset({"num_envs", "vectorization"})
    play_overrides: ClassVar[dict[str, Any]] = {}

    num_envs: int = Field(16, gt=0, description="parallel environments (rl_zoo3's 16)")
    vectorization: Literal["sync", "async"] = Field(
        "sync", description="gymnasium's SyncVectorEnv (one process) or AsyncVectorEnv")
    max_episode_steps: int | None = Field(
        None, gt=0, description="time-out in steps; None keeps the id's registered one")
    kwargs: dict[str, Any] = Field(default_factory=dict,
                                   description="keyword arguments of gymnasium.make")
