"""The batched environment: a gymnasium VectorEnv of torch tensors `[num_envs, ...]`."""

from __future__ import annotations

import math
import reprlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import mujoco
import numpy as np
import torch
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from labcli.envs import metrics
from labcli.envs.compiled import CompiledStep, compiling_notice
from labcli.envs.config import TaskConfig
from labcli.envs.cuda_graph import GraphedStep
from labcli.envs.markers import Marker
from labcli.envs.random import BLOCKS, EnvRandom
from labcli.envs.render.scene import SceneRenderer
from labcli.envs.sim import default_backend, make_sim
from labcli.envs.spec import TaskSpec
from labcli.errors import LabError, LabTypeError, LabValueError, first_line

if TYPE_CHECKING:
    from labcli.envs.sim.chunks import ShardPhysics

UNSTABLE = "unstable"


# The info key of lab's episode figures: gymnasium's RecordEpisodeStatistics owns "episode".
EPISODE = "lab_episode"
TASK_STATE = "task/"  # the saved env state's keys of the task's own (Task.state)
AUTORESET_MODES = (AutoresetMode.SAME_STEP, AutoresetMode.NEXT_STEP)
# Totals of episode figures in, their sums over the ranks of a data-parallel run out.
Reduce = Callable[[torch.Tensor], torch.Tensor]


class LabVecEnv(gym.vector.VectorEnv):
    """Steps all envs at once. By default ended envs reset in the same step
    (`info["final_obs"]` keeps their last observation); with `autoreset_mode=NEXT_STEP` they
    reset on the next step, whose action they ignore, as gymnasium's own vector envs do.
    Episode statistics accumulate on the device and are read once per training iteration with
    `pop_stats()`, so stepping never waits on the host."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}
    render_mode = "rgb_array"  # env 0, see `render`

    def __init__(self, spec: TaskSpec, cfg: TaskConfig, *, backend: str | None = None,
                 device: str = "cpu", seed: int = 0,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.SAME_STEP,
                 shard: tuple[int, int] | None = None, physics: ShardPhysics | None = None):
        """`shard=(first, total)`: these `cfg.num_envs` envs are envs `[first, first + num_envs)`
        of `total` (the cpu backend's env shards; they draw as those envs of one env would);
        `physics`: where and how such a shard's physics steps (`labcli.envs.sim.chunks`)."""
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        seed = checked_seed(seed)
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode}
        self.task_spec = spec
        self.cfg = cfg
        model = spec.task_class.build_model(cfg, spec.model)
        self.step_dt = model.opt.timestep * cfg.decimation
        steps = cfg.episode_length_s / self.step_dt
        if not steps < 2**31:
            raise LabError(f"an episode of {cfg.episode_length_s:g} s is {steps:.3g} env steps of "
                           f"{self.step_dt:g} s", "shorten episode_length_s or raise sim_dt")
        # Rounded first: 0.14 / 0.02 is 7.000000000000001, which must be 7 steps, not 8.
        self.max_episode_length = math.ceil(round(steps, 9))
        self.backend = backend or default_backend(device)
        self.sim = make_sim(self.backend, model, cfg.num_envs, device, cfg.threads, cfg.nconmax,
                            cfg.njmax, spec.task_class.per_env_fields(cfg), physics)
        self.sim.unstable_velocity = cfg.unstable_velocity
        self.task = spec.task_class(cfg, self.sim)
        self.num_envs = cfg.num_envs
        self.device = self.sim.device

        self.observation_names = list(self.task.observation_names)
        self.action_names = list(self.task.action_names)
        self.single_observation_space = gym.spaces.Box(
            -np.inf, np.inf, (len(self.observation_names),), np.float32)
        self.clip_actions = cfg.clip_actions
        self.single_action_space = gym.spaces.Box(-cfg.clip_actions, cfg.clip_actions,
                                                  (len(self.action_names),), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        # The critic's own observations (`info["critic_obs"]` at each step and reset), of a
        # task that gives them: their width, 0 without.
        critic = self.task.critic_observations()
        self.critic_observation_size = 0 if critic is None else critic.shape[1]

        reward_weights = cfg.weights(self.step_dt)
        self.reward_names = list(reward_weights)
        term_names = set(self.task.reward_terms())
        if term_names != set(self.reward_names):
            raise LabError(
                f"task '{spec.name}' computes reward terms {sorted(term_names)} but its config "
                f"weighs {sorted(self.reward_names)}",
                "give reward_weights exactly one entry per reward term")
        weights = torch.tensor([reward_weights[k] for k in self.reward_names],
                               device=self.device)
        self.termination_names = [*self.task.terminations(), UNSTABLE]
        unknown = set(self.task.success_causes) - set(self.termination_names[:-1])
        if unknown:
            raise LabError(f"task '{spec.name}' counts {sorted(unknown)} as success, which are "
                           f"not among its terminations {self.termination_names[:-1]}",
                           "name terminations() causes in success_causes")
        self._success_rows = torch.tensor(
            [i for i, name in enumerate(self.termination_names)
             if name in self.task.success_causes], dtype=torch.long, device=self.device)
        self.metric_names = list(self.task.episode_metrics())
        self._shortcuts = self._reads_on_the_host()
        first, total = shard or (0, self.num_envs)
        self._whole = total  # a list of seeds has one per env of the whole env (`one_seed`)
        # A GPU env is never sharded: one generator makes each draw one kernel, not one a block.
        self.rng = EnvRandom(self.num_envs, self.device, first, total,
                             reads_masks=self._shortcuts,
                             blocks=1 if self.device.type == "cuda" else BLOCKS)
        self.rng.manual_seed(seed)
        self.task.rng = self.rng
        self._np_random, self._np_random_seed = gym.utils.seeding.np_random(seed)

        n, dev = self.num_envs, self.device
        k, t, m = len(self.reward_names), len(self.termination_names), len(self.metric_names)
        self.episode_length = torch.zeros(n, dtype=torch.long, device=dev)
        # Per-env figures are kept as rows over the envs (`[figure, num_envs]`) or tiled to the
        # full shape: an op that broadcasts over a short last dimension steps through the envs
        # one at a time, at 1024 envs several times the cost of one flat loop.
        # The return and the per-term sums, a row each: one op clears or copies them all.
        sums = self._episode_sums = torch.zeros(1 + k, n, device=dev)
        self.episode_return, self.episode_terms = sums[0], sums[1:].t()
        self._weights = weights.expand(n, k).contiguous()
        self.task.weigh(self._weights)
        self._weighted = torch.empty(n, k, device=dev)
        # One row per figure that `pop_stats` reports, one column per env (see `_accumulate`),
        # and where each figure goes in it: views made once, each shaped like its figure.
        # A task's metrics take two rows each: their sums, and how many ended episodes they
        # apply to (a NaN figure does not), so that each is the mean of its own episodes.
        self._ended = torch.empty(5 + k + t + 2 * m, n, dtype=torch.float64, device=dev)
        e = self._ended
        self._ended_figures = (e[0], e[1:2 + k], e[2 + k], e[3 + k], e[4 + k:4 + k + t],
                               e[4 + k + t], *([e[5 + k + t:5 + k + t + m]] if m else []))
        self._metric_counts = e[5 + k + t + m:]
        self._stats = torch.zeros(len(e), dtype=torch.float64, device=dev)
        self._all = torch.ones(n, dtype=torch.bool, device=dev)
        # NEXT_STEP: the envs that ended on the last step, to be reset on this one.
        self._pending = torch.zeros(n, dtype=torch.bool, device=dev)
        self._none = torch.zeros(n, dtype=torch.bool, device=dev)  # read only
        # Without shortcuts: the envs whose action was not finite, from before the physics to
        # after it (a compiled step's two parts).
        self._bad_action = torch.zeros(n, dtype=torch.bool, device=dev)
        self._renderer: SceneRenderer | None = None
        self._resume_state: dict[str, torch.Tensor] | None = None
        self._staggered = False
        # On a GPU the step is host-bound when eager: it replays as one CUDA graph instead.
        self._graphed = (GraphedStep(self._step, self.rng.generators, f"the env step of task "
                                     f"'{spec.name}'")
                         if self.device.type == "cuda" and cfg.cuda_graph else None)
        # On the CPU the step's torch code is traced and compiled on request, in two parts: the
        # physics between them is MuJoCo's.
        what = f"the env step of task '{spec.name}'"
        # The outputs the compiled part writes: tensors all (a task without critic
        # observations has none to pass).
        self._written = tuple(f.name for f in fields(StepOutputs)
                              if f.name not in CRITIC_OUTPUTS or self.critic_observation_size)
        self._compiled = ((CompiledStep(self._act, what, self.rng), CompiledStep(
            lambda *out: self._settle(StepOutputs(**dict(zip(self._written, out, strict=True))),
                                      self._bad_action), what, self.rng))
            if self.device.type == "cpu" and cfg.compile else None)

    @property
    def threads(self) -> int | None:
        """The cpu backend's physics threads; None on a GPU."""
        return getattr(self.sim, "nthread", None)

    # gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | Sequence[int] | None = None,
              options: dict[str, Any] | None = None):
        if self.closed:
            raise closed_error("reset", self.task_spec.name)
        if seed is not None:
            seed = self.one_seed(seed)
        mask = reset_mask(options, self.num_envs, self.device)  # all checked, then done
        if seed is not None:
            self.rng.manual_seed(seed)
            self._np_random, self._np_random_seed = gym.utils.seeding.np_random(seed)
        if mask is None and self._resume_state is not None:
            self.set_state(self._resume_state)
            self._resume_state = None
            self._stats.zero_()
        elif mask is None:
            self._reset_envs(self._all)
            if self._staggered:
                self._staggered = False
                # In place: a GPU step's CUDA graph reads this tensor.
                self.episode_length.copy_(self.rng.rand() * self.max_episode_length)
            self._stats.zero_()
        else:  # gymnasium's way to reset some envs only
            self._reset_envs(mask)
        return self.observations(), self.critic_info()

    def critic_info(self, out: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """`{"critic_obs": ...}` of the state observed last (in `out`, if given); {} for a
        task without them."""
        return ({"critic_obs": self.critic_observations(out)} if self.critic_observation_size
                else {})

    def critic_observations(self, out: torch.Tensor | None = None) -> torch.Tensor:
        """The task's critic observations of the state observed last (in `out`, if given), as
        `observations` returns the policy's."""
        return _observed(self.task.critic_observations(), out)

    def one_seed(self, seed: int | Sequence[int]) -> int:
        """All envs share one seed: a list of seeds, one per env (as gymnasium's
        SyncVectorEnv takes them), is folded into one seed that depends on every one (a shard's:
        one per env of the whole env). Anything else is a LabTypeError or LabValueError saying
        what reset(seed=...) takes."""
        takes = (f"reset(seed=...) must be None, a non-negative int or a list of "
                 f"{self._whole} non-negative ints (one per env), got {_shown(seed)}")
        seeds = seed.tolist() if isinstance(seed, (np.ndarray, torch.Tensor)) else seed
        if _is_int(seeds):
            if seeds < 0:
                raise LabValueError(takes)
            return int(seeds)
        if not isinstance(seeds, (list, tuple)) or not all(_is_int(s) for s in seeds):
            raise LabTypeError(takes)
        if len(seeds) != self._whole or any(s < 0 for s in seeds):
            raise LabValueError(takes)
        return int(np.random.SeedSequence([int(s) for s in seeds]).generate_state(1)[0])

    def step(self, actions: torch.Tensor):
        if self.closed:
            raise closed_error("step", self.task_spec.name)
        actions = checked_actions(actions, self.action_space.shape, self.device)
        if self._graphed is not None:
            outputs = self._graphed(actions)
            self.task.replayed()
            return outputs
        if self._compiled is not None:
            out = self.new_outputs()
            if self._compiled[1].ready:
                self._compiled_step(actions, out)
            else:
                with compiling_notice():
                    self._compiled_step(actions, out)
            return self.returned(out)
        return self._step(actions)

    def step_into(self, actions: torch.Tensor, out: StepOutputs) -> None:
        """`step`, its outputs written into `out` (an env shard's rows of the shared buffers)
        rather than into new tensors: each output is an op's `out=`, where copying the step's
        outputs there would be one op more for each. `actions` are taken as they are: a float32
        `[num_envs, actions]` tensor on the env's device, which the sharded env checked before
        it copied them into the shared buffer."""
        if self.closed:
            raise closed_error("step", self.task_spec.name)
        if self._compiled is not None:
            self._compiled_step(actions, out)
        else:
            self._step(actions, out)

    def new_outputs(self, num_envs: int | None = None,
                    make: Callable[[torch.Tensor], torch.Tensor] = lambda t: t) -> StepOutputs:
        """New tensors for every output of a step (`step_into`) of `num_envs` envs (this env's by
        default), each through `make` (e.g. into shared memory)."""
        n, obs, dev = num_envs or self.num_envs, len(self.observation_names), self.device
        bools = {name: torch.zeros(n, dtype=torch.bool, device=dev)
                 for name in ("terminated", "truncated", "done", "success")}
        return StepOutputs(**{name: make(tensor) for name, tensor in {
            "obs": torch.zeros(n, obs, device=dev), "final_obs": torch.zeros(n, obs, device=dev),
            "reward": torch.zeros(n, device=dev), "r": torch.zeros(n, device=dev),
            "l": torch.zeros(n, dtype=torch.long, device=dev), **bools,
            "terminations": torch.zeros(n, len(self.termination_names), dtype=torch.bool,
                                        device=dev),
            **({name: torch.zeros(n, self.critic_observation_size, device=dev)
                for name in CRITIC_OUTPUTS} if self.critic_observation_size else {})}.items()})

    def returned(self, out: StepOutputs) -> tuple:
        """What `step` returns, of a step's outputs written into `out`."""
        info = {EPISODE: {"r": out.r, "l": out.l, "success": out.success},
                f"_{EPISODE}": out.done, "terminations": out.terminations}
        if self.autoreset_mode is AutoresetMode.SAME_STEP:
            info["final_obs"], info["_final_obs"] = out.final_obs, out.done
        if out.critic_obs is not None:
            info["critic_obs"] = out.critic_obs
            if self.autoreset_mode is AutoresetMode.SAME_STEP:
                info["final_critic_obs"] = out.final_critic_obs
        return out.obs, out.reward, out.terminated, out.truncated, info

    def close_extras(self, **kwargs: Any) -> None:
        # VectorEnv.close calls this once, then sets `closed`.
        if self._graphed is not None:
            self._graphed.close()
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self.sim.close()

    def _step(self, actions: torch.Tensor, out: StepOutputs | None = None):
        """The MDP of one env step, as torch operations only (no host syncs, fixed shapes), so
        that on a GPU it replays as a CUDA graph. With `out`, its outputs go there."""
        bad_action = self._act(actions)
        self.sim.step(self.cfg.decimation, self.task.controls, self.task.substep)
        return self._settle(out or _NEW_OUTPUTS, bad_action)

    def _compiled_step(self, actions: torch.Tensor, out: StepOutputs) -> None:
        act, settle = self._compiled
        act(actions.contiguous())  # compiled for a contiguous input
        self.sim.step(self.cfg.decimation, self.task.controls, self.task.substep)
        settle(*(getattr(out, name) for name in self._written))

    def _reads_on_the_host(self) -> bool:
        """Whether the step may read tensors on the host. On the CPU a tensor reads on the host
        for free, and on most steps no env ends, diverges or gets a non-finite action: the step
        asks, and skips the work that would change nothing then (resets, episode figures,
        masking). On a GPU asking would wait for the device and break the step's CUDA graph,
        and a compiled step cannot ask: that work always runs there. Skipping an idle reset
        also decides which blocks draw (`EnvRandom.only_for`); the shortcuts change no output.
        (A method: tests step a CPU env as a GPU steps it.)"""
        return self.device.type == "cpu" and not self.cfg.compile

    def _act(self, actions: torch.Tensor) -> torch.Tensor | None:
        """The step before the physics: the actions made safe and turned into controls. The
        envs whose action was not finite (None: none)."""
        safe, bad_action = self._safe_actions(actions)
        self.task.apply_actions(safe)
        return bad_action

    def _settle(self, o: StepOutputs, bad_action: torch.Tensor | None = None):
        """The step after the physics, into `o`: every term, figure, reset and output."""
        self.task.update()
        self.episode_length += 1

        causes = self.task.terminations()
        unstable = self._unstable(bad_action)
        # A row per cause ([cause, env]): rows stack and reduce faster than short columns.
        terminated = torch.stack([*causes.values(),
                                  self._none if unstable is None else unstable])
        reward = self._reward(unstable, o.reward)

        next_step = self.autoreset_mode is AutoresetMode.NEXT_STEP
        if next_step:
            # The envs that ended on the last step are reset now: their action, physics step and
            # figures of this step do not count.
            live = self._pending.logical_not()
            terminated.logical_and_(live)
            if bad_action is not None:
                bad_action.logical_and_(live)
            reward.masked_fill_(self._pending, 0.0)
        terminated_any = torch.any(terminated, dim=0, out=o.terminated)
        done = torch.logical_or(terminated_any, self.episode_length >= self.max_episode_length,
                                out=o.done)
        time_outs = self.task.time_outs()
        if time_outs is not None:
            done.logical_or_(time_outs)
        if next_step:
            done.logical_and_(live)
        # Timed out and not terminated.
        truncated = torch.logical_xor(done, terminated_any, out=o.truncated)
        self.task.after_step()
        ended = not self._shortcuts or bool(done.any())
        success = (torch.logical_and(self.task.success(truncated), truncated, out=o.success)
                   if ended else _copy(done, o.success))
        if ended and len(self._success_rows):  # a goal reached: ended by a success cause
            success.logical_or_(terminated.index_select(0, self._success_rows).any(dim=0))
        episode = {"r": _copy(self.episode_return, o.r), "l": _copy(self.episode_length, o.l),
                   "success": success}
        if ended:
            self._accumulate(done, success, terminated, bad_action)
        # A view of this step's own tensor needs no copy; a shard's buffer does.
        terminations = (terminated.t() if o.terminations is None
                        else o.terminations.copy_(terminated.t()))
        info = {EPISODE: episode, f"_{EPISODE}": done, "terminations": terminations}
        if next_step:
            self._reset_envs(self._pending)
            self._pending.copy_(done)
            obs = self.observations(o.obs)
            return obs, reward, terminated_any, truncated, info | self.critic_info(o.critic_obs)
        final_obs = info["final_obs"] = self.observations(o.final_obs)
        info["_final_obs"] = done
        if self.critic_observation_size:  # the critic's of the same last state
            info["final_critic_obs"] = self.critic_observations(o.final_critic_obs)
        # With no env reset the state is unchanged: a copy, not the task's terms again.
        reset = ended and self._reset_envs(done)
        obs = self.observations(o.obs) if reset else _copy(final_obs, o.obs)
        if self.critic_observation_size:  # of the state `obs` is of
            info["critic_obs"] = (self.critic_observations(o.critic_obs) if reset
                                  else _copy(info["final_critic_obs"], o.critic_obs))
        return obs, reward, terminated_any, truncated, info

    def _safe_actions(self, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The actions clipped, non-finite ones as 0; and the envs that had one (None: none)."""
        if self._shortcuts and math.isfinite(actions.sum()):  # a sum is finite or it is not
            return actions.clamp(-self.clip_actions, self.clip_actions), None
        safe = actions.nan_to_num(0.0)
        # nan_to_num changed exactly the non-finite entries (NaN equals nothing, inf != max).
        bad_action = torch.any(safe.ne(actions), dim=1,
                               out=None if self._shortcuts else self._bad_action)
        return safe.clamp_(-self.clip_actions, self.clip_actions), bad_action

    def _unstable(self, bad_action: torch.Tensor | None) -> torch.Tensor | None:
        """The envs whose state diverged or whose action was not finite (None: none)."""
        if self._shortcuts and not self.sim.any_unstable():
            return bad_action
        unstable = self.sim.unstable()
        return unstable if bad_action is None else unstable | bad_action

    # looking at env 0 ------------------------------------------------------------------------
    def render(self) -> np.ndarray:
        """Env 0 as an RGB image `[height, width, 3]`, rendered offscreen."""
        if self.closed:
            raise closed_error("render", self.task_spec.name)
        return self._scene().render(self.sim.qpos[0], self.sim.qvel[0], self.markers())

    def markers(self) -> list[Marker]:
        """What env 0's task shows beside its bodies (a commanded target)."""
        return self.task.markers(0)

    def mj_scene(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """The model and an MjData holding env 0's current state, for MuJoCo's viewer."""
        if self.closed:
            raise closed_error("mj_scene", self.task_spec.name)
        renderer = self._scene()
        return renderer.model, renderer.sync(self.sim.qpos[0], self.sim.qvel[0])

    def _scene(self) -> SceneRenderer:
        if self._renderer is None:
            # The model with its visual meshes: the sim's has only what its physics needs.
            self._renderer = SceneRenderer(self.task_spec.task_class.build_model(
                self.cfg, self.task_spec.model, visual=True))
        return self._renderer

    def describe(self) -> dict[str, Any]:
        """What a deployment must know of the policy's inputs and outputs: each observation's
        unit and convention, each action's rule to its command, and the timing."""
        units = self.task.observation_units
        return {
            "observations": [{"name": name, "unit": units.get(name, "")}
                             for name in self.observation_names],
            "actions": self.task.action_commands(),
            "action_range": [-self.clip_actions, self.clip_actions],
            "control_dt": self.step_dt,
            "physics_dt": self.step_dt / self.cfg.decimation,
            "decimation": self.cfg.decimation,
            **({"deployment": deployed} if (deployed := self.task.deployment()) else {}),
        }

    # resume ----------------------------------------------------------------------------------
    def get_state(self) -> dict[str, torch.Tensor]:
        """What continues every episode exactly where it is: the sim's positions, velocities and
        controls (what tasks read and write), episode counters, what the task carries from step
        to step (`Task.state`: commands, timers, per-env physics) and the random generators."""
        return {**{name: target.clone() for name, target in self._state_targets().items()},
                "generator": self.rng.get_state()}

    def _state_targets(self) -> dict[str, torch.Tensor]:
        return {"qpos": self.sim.qpos, "qvel": self.sim.qvel, "ctrl": self.sim.ctrl,
                "episode_length": self.episode_length, "episode_return": self.episode_return,
                "episode_terms": self.episode_terms,
                **{TASK_STATE + name: t for name, t in self.task.state().items()}}

    def check_state(self, state: Any, num_envs: int | None = None,
                    rng: EnvRandom | None = None) -> None:
        """Raise a LabError unless `state` is one `get_state` of this env could have returned:
        checked before a resumed run writes anything, so a damaged file cannot fail it later.
        `num_envs` and `rng`: of a whole env of which this one is a shard."""
        if not isinstance(state, dict):
            raise LabError(f"saved env state is a {type(state).__name__}, not a mapping")
        for name, target in self._state_targets().items():
            value = state.get(name)
            if value is None and name.startswith(TASK_STATE):
                continue  # saved by a lab before tasks' state was: their episodes go on without
            shape = (num_envs or self.num_envs, *target.shape[1:])
            if not isinstance(value, torch.Tensor) or tuple(value.shape) != shape:
                shown = tuple(value.shape) if isinstance(value, torch.Tensor) else repr(value)
                raise LabError(f"saved env state '{name}' is {shown}, this env's {shape}",
                               "resume with the num_envs and task the checkpoint was trained with")
        generator = state.get("generator")
        if isinstance(generator, torch.Tensor) and generator.dim() == 1:
            raise LabError("saved env state has one random generator for all envs: a lab from "
                           "before envs drew per block of envs saved it",
                           "resume it with the lab that saved it, or train anew")
        try:
            (rng or self.rng).check_state(generator)
        except (TypeError, ValueError, RuntimeError) as exc:
            raise LabError(f"saved env state's random generator is damaged: {first_line(exc)}"
                           ) from None

    def set_state(self, state: dict[str, torch.Tensor]) -> None:
        task_saved = {name.removeprefix(TASK_STATE): value for name, value in state.items()
                      if name.startswith(TASK_STATE)}
        state = {**state, **{TASK_STATE + name: value for name, value
                             in self.task.upgraded_state(task_saved).items()}}
        self.check_state(state)  # all checked before any is changed
        for name, target in self._state_targets().items():
            if name in state:
                target.copy_(state[name])
        self.rng.set_state(state["generator"])
        self.task.state_restored()
        self.task.update()

    def __reduce__(self):
        # MuJoCo's rollout and data objects do not pickle: a pickled or deep-copied env is built
        # anew from its spec and config, then put in this one's exact state.
        return (_rebuilt, (self.task_spec, self.cfg, self.backend, str(self.device),
                           self.autoreset_mode),
                {**self.get_state(), "pending": self._pending.clone(),
                 "stats": self._stats.clone(), "np_random": self._np_random.bit_generator.state,
                 "np_random_seed": self._np_random_seed})

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.set_state(state)
        self._pending.copy_(state["pending"])
        self._stats.copy_(state["stats"])
        self._np_random.bit_generator.state = state["np_random"]
        self._np_random_seed = state["np_random_seed"]

    def resume_from(self, state: dict[str, torch.Tensor]) -> None:
        """Make the next full `reset()` continue the saved episodes instead of starting new ones:
        every library resets its env once before training, and a resumed run must go on from
        where the checkpoint left off, as if it had never stopped."""
        self._resume_state = state

    def start_staggered(self) -> None:
        """Make the next full `reset()` start each env's episode at a random step in [0, the
        time-out) (`stagger_episodes`), as a fresh training run does."""
        self._staggered = True

    # statistics ------------------------------------------------------------------------------
    def _accumulate(self, done: torch.Tensor, success: torch.Tensor, terminated: torch.Tensor,
                    bad_action: torch.Tensor | None) -> None:
        """Add the ended episodes' figures to the running sums: each figure is copied into its
        rows of one float64 matrix (no stack or cat of mixed dtypes), which are summed over the
        envs weighted by `done` in one matrix-vector product, not an op per figure. A non-finite
        action always ends its episode, so `done` weights count those too."""
        figures = (done, self._episode_sums, self.episode_length, success, terminated,
                   self._none if bad_action is None else bad_action)
        if self.metric_names:
            figures += (torch.stack(list(self.task.episode_metrics().values())),)
        for rows, figure in zip(self._ended_figures, figures, strict=True):
            rows.copy_(figure)
        if self.metric_names:
            sums = self._ended_figures[-1]
            torch.eq(sums, sums, out=self._metric_counts)  # 1 where it applies: NaN != NaN
            sums.nan_to_num_(nan=0.0)
        self._stats.addmv_(self._ended, self._ended_figures[0])

    def pop_stats(self, reduce: Reduce | None = None) -> dict[str, float]:
        """Means over the episodes that ended since the last call, under `metrics` tags; empty
        when none ended. One host sync: call it once per training iteration, not per step.
        `reduce` sums the figures' totals over several envs' (data-parallel ranks) first."""
        values = self._stats if reduce is None else reduce(self._stats)
        stats = self.summarize_stats(values)
        self._stats.zero_()
        overflows = {metrics.OVERFLOW + name: n for name, n in self.sim.pop_overflows().items()}
        return {**stats, **overflows}

    @property
    def stats_size(self) -> int:
        """How many figures the running sums of ended episodes hold (`keep_stats_in`)."""
        return len(self._stats)

    def keep_stats_in(self, out: torch.Tensor) -> None:
        """Keep the running sums of ended episodes' figures in `out` from now on, which takes
        those so far: an env shard's row of shared memory, which the whole env reads, instead
        of a copy into it every step."""
        out.copy_(self._stats)
        self._stats = out

    def summarize_stats(self, totals: torch.Tensor) -> dict[str, float]:
        """The means `pop_stats` reports, from sums laid out as this env keeps them."""
        values = totals.tolist()
        count = values[0]
        if count == 0:
            return {}
        k = len(self.reward_names)
        stats = {
            metrics.EPISODES: count,
            metrics.MEAN_RETURN: values[1] / count,
            metrics.MEAN_LENGTH: values[2 + k] / count,
            metrics.SUCCESS_RATE: values[3 + k] / count,
        }
        for name, total in zip(self.reward_names, values[2:2 + k], strict=True):
            stats[metrics.REWARD_TERM + name] = total / count
        t = len(self.termination_names)
        terminations = values[4 + k:4 + k + t]
        for name, total in zip(self.termination_names, terminations, strict=True):
            stats[metrics.TERMINATION + name] = total / count
        stats[metrics.INSTABILITIES] = terminations[-1]
        stats[metrics.NONFINITE_ACTIONS] = values[4 + k + t]
        m = len(self.metric_names)
        totals, counts = values[5 + k + t:5 + k + t + m], values[5 + k + t + m:]
        for name, total, counted in zip(self.metric_names, totals, counts, strict=True):
            if counted:
                stats[metrics.TASK_METRIC + name] = total / counted
        return stats

    # internals -------------------------------------------------------------------------------
    def _reset_envs(self, mask: torch.Tensor) -> bool:
        """Reset the envs in `mask`; False where it knows that none was (and did nothing).
        On the CPU, asking whether any env ended is free, and most steps none does: the reset
        path (the task's draws, masked writes) is skipped then. On a GPU the question would
        wait for the device and break the step's CUDA graph: the masked reset always runs."""
        with self.rng.only_for(mask) as some:
            if not some:
                return False
            self.sim.reset_to_defaults(mask)
            self.task.reset(mask, self.rng)
        self.task.update()
        self.episode_length.masked_fill_(mask, 0)
        self._episode_sums.masked_fill_(mask, 0.0)
        if self.autoreset_mode is AutoresetMode.NEXT_STEP:  # else none is ever pending
            # Last: `mask` may be `_pending` itself.
            self._pending.logical_and_(mask.logical_not())
        return True

    def _reward(self, unstable: torch.Tensor | None, out: torch.Tensor | None) -> torch.Tensor:
        """The weighted terms' sum (into `out`, if given); each weighted term also adds to its
        episode's total."""
        terms = self.task.reward_terms()
        rows = torch.stack([terms[name] for name in self.reward_names])  # contiguous copies
        if unstable is not None:  # a diverged env's state is garbage: it earns nothing
            rows.masked_fill_(unstable, 0.0)
        # Cast and transposed in one copy: half the cost of stacking columns of another dtype.
        weighted = self._weighted.copy_(rows.t())
        weighted.mul_(self._weights).nan_to_num_(0.0, 0.0, 0.0)
        reward = torch.sum(weighted, dim=1, out=out)
        self.episode_return += reward
        self.episode_terms += weighted
        return reward

    def observations(self, out: torch.Tensor | None = None) -> torch.Tensor:
        """The current observations: what the last step or reset returned (in `out`, if given:
        the cast is the copy into it)."""
        return _observed(self.task.observations(), out)


@dataclass(frozen=True)
class StepOutputs:
    """Where a step writes its outputs (`LabVecEnv.step_into`); None: into a new tensor."""

    obs: torch.Tensor | None = None
    final_obs: torch.Tensor | None = None
    reward: torch.Tensor | None = None
    terminated: torch.Tensor | None = None
    truncated: torch.Tensor | None = None
    done: torch.Tensor | None = None
    r: torch.Tensor | None = None
    l: torch.Tensor | None = None  # noqa: E741 - gymnasium's episode length key
    success: torch.Tensor | None = None
    terminations: torch.Tensor | None = None
    # A task's critic observations, where it has them: the step's, and an ended env's last.
    critic_obs: torch.Tensor | None = None
    final_critic_obs: torch.Tensor | None = None


CRITIC_OUTPUTS = ("critic_obs", "final_critic_obs")


_NEW_OUTPUTS = StepOutputs()


def _observed(obs: torch.Tensor, out: torch.Tensor | None) -> torch.Tensor:
    """Observations as a step returns them: float32, NaN and infinities as 0 (into `out`, if
    given: the cast is the copy into it)."""
    if out is None:
        return obs.to(torch.float32).nan_to_num(0.0, 0.0, 0.0)
    return out.copy_(obs).nan_to_num_(0.0, 0.0, 0.0)


def _copy(value: torch.Tensor, out: torch.Tensor | None) -> torch.Tensor:
    return value.clone() if out is None else out.copy_(value)


def checked_actions(actions: Any, shape: Sequence[int], device: torch.device) -> torch.Tensor:
    """`actions` as a float32 tensor on `device`; a LabError unless they are `[envs, actions]`."""
    actions = torch.as_tensor(actions, device=device, dtype=torch.float32)
    if actions.shape != tuple(shape):
        n, k = shape
        raise LabError(f"actions of shape {tuple(actions.shape)} for an env of {n} envs with "
                       f"{k} actions each", f"pass a [{n}, {k}] tensor")
    return actions


class ClosedEnvError(LabValueError, gym.error.ClosedEnvironmentError):
    """A closed env asked to reset, step or render: a ValueError, as Python's closed files raise,
    and gymnasium's ClosedEnvironmentError, as its AsyncVectorEnv raises."""


def closed_error(method: str, task: str) -> ClosedEnvError:
    return ClosedEnvError(f"{method}() after close(): this env of task '{task}' is closed",
                          "make a new env")


def _is_int(value: Any) -> bool:
    """An int as gymnasium's seeds are (NumPy's too), not a bool."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _shown(value: Any) -> str:
    """`value` as an error quotes it: short, and on one line (a tensor's repr has several)."""
    return " ".join(reprlib.repr(value).split())


def checked_seed(seed: Any, what: str = "seed") -> int:
    """`seed` as an int; a LabTypeError or LabValueError unless it is a non-negative int (any
    size, as gymnasium takes them), checked where an env is made, before anything is built."""
    if not _is_int(seed) or seed < 0:
        error = LabValueError if _is_int(seed) else LabTypeError
        raise error(f"{what} must be a non-negative int, got {_shown(seed)}"
                    + ("" if _is_int(seed) else f" ({type(seed).__name__})"))
    return int(seed)


def reset_mask(options: Any, num_envs: int, device: torch.device | str) -> torch.Tensor | None:
    """`options["reset_mask"]` of `reset(options=...)` as a bool tensor on `device` (None: no
    mask). gymnasium's vector envs take a NumPy bool array of shape `(num_envs,)`; lab's also a
    torch bool tensor or a list of bools. Anything else (ints, which could be indices; the wrong
    shape) is a LabTypeError or LabValueError naming what was given."""
    if options is None:
        return None
    if not isinstance(options, Mapping):
        raise LabTypeError(f"reset(options=...) must be a dict or None, got "
                           f"{type(options).__name__}")
    mask = options.get("reset_mask")
    if mask is None:
        return None
    takes = (f"options['reset_mask'] must be {num_envs} bools, one per env (a NumPy array, "
             "torch tensor or list of dtype bool)")
    if isinstance(mask, (list, tuple)):
        try:
            mask = np.asarray(mask)
        except ValueError:  # ragged
            raise LabValueError(f"{takes}, got a ragged {type(mask).__name__}") from None
    if not isinstance(mask, (np.ndarray, torch.Tensor)):
        raise LabTypeError(f"{takes}, got {type(mask).__name__}")
    if mask.dtype not in (np.bool_, torch.bool):
        raise LabTypeError(f"{takes}, got dtype {mask.dtype}")
    if tuple(mask.shape) != (num_envs,):
        raise LabValueError(f"{takes}, got shape {tuple(mask.shape)}")
    return torch.as_tensor(mask, device=device)


def _rebuilt(spec: TaskSpec, cfg: TaskConfig, backend: str, device: str,
             autoreset_mode: AutoresetMode) -> LabVecEnv:
    return LabVecEnv(spec, cfg, backend=backend, device=device, autoreset_mode=autoreset_mode)


def _autoreset_mode(mode: AutoresetMode | str) -> AutoresetMode:
    """An AutoresetMode, or its value or name in any spelling ("NextStep", "next_step",
    "NEXT_STEP"); anything else is a LabValueError (a LabTypeError if not a string)."""
    if isinstance(mode, AutoresetMode) and mode in AUTORESET_MODES:
        return mode
    hint = ("use AutoresetMode.SAME_STEP (the default) or AutoresetMode.NEXT_STEP, or their "
            "names: 'same_step', 'next_step'")
    if not isinstance(mode, (str, AutoresetMode)):
        raise LabTypeError(f"autoreset_mode must be an AutoresetMode or a string, got "
                           f"{_shown(mode)} ({type(mode).__name__})", hint)
    key = str(getattr(mode, "value", mode)).replace("_", "").lower()
    for known in AUTORESET_MODES:
        if known.value.lower() == key:
            return known
    raise LabValueError(f"autoreset_mode {mode!r} is not one lab's env has", hint)
