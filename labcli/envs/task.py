"""The public task API: batched torch functions over a Sim, configured by a `TaskConfig`.

A task is written once with torch operations on `[num_envs, ...]` tensors, so it runs unchanged
on every backend. Plugins register a `TaskSpec` (labcli/envs/spec.py) naming it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import mujoco
import torch

from labcli.envs import models
from labcli.envs.config import TaskConfig
from labcli.envs.markers import Marker
from labcli.envs.models import ModelSource
from labcli.envs.random import EnvRandom
from labcli.envs.sim import Sim


class Task:
    """Batched MDP terms over `sim`; subclasses override the methods below with torch code."""

    observation_names: ClassVar[list[str]]
    action_names: ClassVar[list[str]]
    # What a deployment must know of each observation, by name: its unit and convention, e.g.
    # "rad; 0 upright, counter-clockwise positive, wrapped to [-pi, pi)". Exported with the
    # policy (exported/policy.onnx.json).
    observation_units: ClassVar[Mapping[str, str]] = {}
    # The unit of each action's command, by action name (e.g. {"cart_force": "N"}).
    action_units: ClassVar[Mapping[str, str]] = {}

    # The env's random numbers, set by the env before the first reset: draw from it
    # (`rng.uniform_(out)`, `rng.normal_(out)` on `[num_envs, ...]` tensors), not from torch's
    # global generator, so that seeded runs repeat, on any number of threads (and a CUDA graph
    # replays the draws).
    rng: EnvRandom

    # Each physics step's controls of the coming env step, `[decimation, num_envs, nu]`, that
    # `apply_actions` writes where controls change inside a step (a motor's latency); None: the
    # physics holds `sim.ctrl` through the step.
    controls: torch.Tensor | None = None
    # Called before each physics step k (0 <= k < decimation) of an env step with k, to write
    # `sim.ctrl` from the state then (a motor model's torques, `acts_each_physics_step`); None:
    # the physics steps `controls` or `sim.ctrl` as they are.
    substep: Callable[[int], None] | None = None

    def __init__(self, cfg: TaskConfig, sim: Sim):
        self.cfg = cfg
        self.sim = sim
        self.step_dt = sim.model.opt.timestep * cfg.decimation  # seconds an env step lasts
        # The env's reward weights `[num_envs, terms]` (per step, in its `reward_names`
        # order), which a task may change in place as training goes on (a curriculum).
        self.reward_weights: torch.Tensor | None = None

    def weigh(self, weights: torch.Tensor) -> None:
        """Called once by the env with its reward weights (`reward_weights`)."""
        self.reward_weights = weights

    @classmethod
    def build_model(cls, cfg: TaskConfig, source: ModelSource,
                    visual: bool = False) -> mujoco.MjModel:
        """The MjModel this task steps, from the spec's model (an MJCF file or a Menagerie
        robot): a task may edit its `mujoco.MjSpec` first (add the sensors its terms read).
        `cfg.sim_dt`, where set, is the physics step. Without `visual`, the physics only
        (`models.drop_visual_meshes`); with it, for rendering."""
        spec = models.load_spec(source)
        if not visual:
            models.drop_visual_meshes(spec)
        model = spec.compile()
        models.set_options(model, cfg)
        return model

    @classmethod
    def acts_each_physics_step(cls, cfg: TaskConfig) -> bool:
        """Whether a task made with `cfg` sets `substep`: the cpu backend's env shards then
        step their physics one physics step at a time. The default: no."""
        return False

    @classmethod
    def per_env_fields(cls, cfg: TaskConfig) -> tuple[str, ...]:
        """MjModel fields (e.g. "geom_friction", "body_mass") that this task varies per env,
        through `sim.model_field`: the sim is made with them. The default: none."""
        return ()

    def apply_actions(self, actions: torch.Tensor) -> None:
        """Turn actions (clipped to ±`clip_actions`) into controls; the default scales them into
        ctrl."""
        torch.mul(actions, self.cfg.action_scale, out=self.sim.ctrl)

    def action_commands(self) -> list[dict[str, Any]]:
        """How each action in [-1, 1] becomes a command to the robot, for exported metadata:
        per action, the actuator it drives, the rule and the command's unit. This describes the
        default `apply_actions`; a task that overrides it overrides this too."""
        model = self.sim.model
        return [{"action": action, "actuator": actuator_name(model, i),
                 "command": f"ctrl = {self.cfg.action_scale:g} * action",
                 "unit": self.action_units.get(action, "")}
                for i, action in enumerate(self.action_names)]

    def update(self) -> None:
        """Called by the env each time the sim's state changed (after the physics steps, a reset
        or a restore), before it reads any term: compute here, once, what several terms share
        (cartpole: the wrapped pole angle), instead of once per term. Write the results into
        tensors made once (`out=`, in-place ops): on a GPU the env step replays as a CUDA graph,
        which writes into the tensors it was captured with. The default does nothing."""

    def observations(self) -> torch.Tensor:
        raise NotImplementedError

    def critic_observations(self) -> torch.Tensor | None:
        """The critic's own observations `[num_envs, k]`, of the state the last
        `observations()` call observed (a tensor kept and rewritten by each call), for the
        learners that read them (an actor-critic's privileged, noise-free inputs); None: the
        critic reads the policy's observations. The default: None."""
        return None

    def reward_terms(self) -> dict[str, torch.Tensor]:
        """Unweighted reward terms by name; the weights come from `cfg.reward_weights`."""
        raise NotImplementedError

    def terminations(self) -> dict[str, torch.Tensor]:
        """Boolean `[num_envs]` per termination cause (time-outs are the env's business)."""
        return {}

    def deployment(self) -> dict[str, Any]:
        """What a deployer wires around the exported policy besides its inputs' names and
        units: for a robot, each action's joint, default position, gains, limits, scale and
        offset, each observation term's scale and clip, each command's ranges. `lab export`
        writes it into the metadata. The default: nothing more."""
        return {}

    def time_outs(self) -> torch.Tensor | None:
        """Boolean `[num_envs]`: envs whose episode ends now as a time-out, besides the
        episode's length (Isaac Lab's terminations with `time_out=True`, such as a robot at the
        terrain's edge): truncated, not terminated, so learners bootstrap from their value.
        The default: None, no such cause."""
        return None

    def state(self) -> dict[str, torch.Tensor]:
        """The task's own per-env tensors (`[num_envs, ...]`) that carry from one step to the
        next beyond the sim's state (a command, its timer, per-env masses), by name: the env
        saves them with its state and restores them in place, so that a resumed run or a copy
        goes on exactly. The default: none."""
        return {}

    def state_restored(self) -> None:
        """Called after `state()`'s tensors were written from a saved state."""

    def upgraded_state(self, saved: dict[str, Any]) -> dict[str, Any]:
        """`saved` (a saved `state()`) in this lab's names, where an older lab saved some of
        the tensors differently. The default: as saved."""
        return saved

    def replayed(self) -> None:
        """Called after an env step replayed as a CUDA graph, in which none of the task's
        Python ran: drop what `update()` and the terms keep in Python for the state they last
        saw (a cache keyed by state), so that code reading the task between steps computes
        it from the state the graph left. The default does nothing."""

    def reset(self, mask: torch.Tensor, rng: EnvRandom) -> None:
        """Randomize the state of the envs in `mask`; the sim already put them at the defaults."""

    def after_step(self) -> None:
        """Called once per env step, after its rewards and terminations and before its success
        and observations: advance what the task carries from step to step (a command's timer,
        the feet's air time). The default does nothing."""

    def success(self, time_out: torch.Tensor) -> torch.Tensor:
        """Whether each episode that reached its time-out succeeded, judged on its final
        state."""
        return torch.zeros_like(time_out)

    # Termination causes (names of `terminations()`) that end an episode as a success: a goal
    # reached ends it early, and counts besides the episodes `success` judges at the time-out.
    success_causes: frozenset[str] = frozenset()

    def markers(self, env: int) -> list[Marker]:
        """What videos and the viewer show of env `env` beside its bodies (a commanded target,
        labcli/envs/markers.py); the default shows nothing."""
        return []

    def episode_metrics(self) -> dict[str, torch.Tensor]:
        """Figures per env `[num_envs]` about the episode so far (e.g. a command's mean tracking
        error), read when episodes end: their mean over the ended episodes is logged as
        `Metrics/<name>`. A NaN where a figure does not apply to an env (a level of one terrain
        type): the mean is over the episodes it applies to, and none is logged while none of
        those ended. The same names on every call; the default has none."""
        return {}


def actuator_name(model: mujoco.MjModel, i: int) -> str:
    """Actuator `i`'s name; an unnamed one's, after the joint it drives ("actuator 3 (knee)")."""
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i)
    if name:
        return name
    joint = (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, int(model.actuator_trnid[i, 0]))
             if model.actuator_trntype[i] == int(mujoco.mjtTrn.mjTRN_JOINT) else None)
    return f"actuator {i} ({joint})" if joint else f"actuator {i}"
