"""`RobotTask`: a task assembled from the terms its config lists (labcli/envs/mdp/config.py),
in the manner of Isaac Lab's manager-based envs, without the managers: the groups are pydantic
models, each term's code a function or a small class named by its config.

A term's code is either a function `f(task, cfg) -> Tensor`, called every step, or a class made
once as `Term(task, cfg)` and called every step, which may also have:
- `pre_physics()`: before the physics steps (remember what the step changes: progress, rates);
- `after_step()`: once per step, after its rewards and terminations (advance what the term
  carries from step to step: a command's timer, the feet's air time);
- `reset(mask)`: after the envs in `mask` were reset (events draw their state here);
- `metrics()`: figures per env about the episode so far, logged as `Metrics/<term>/<key>`
  (NaN where one does not apply to an env);
- `carried`: names of its per-env tensors that carry from step to step (a command, a timer,
  the feet's air time), saved with the env's state and restored in place (`Task.state`), and
  `restored()`, called after they were;
- `names`: observation column names;
- `sensors(model, cfg)` (a staticmethod): the MuJoCo sensors it reads (labcli/envs/mdp/sensors.py),
  added to the model before it is compiled.
State that several terms read and carry from step to step (the feet's contacts) is an object
they share through `task.shared`, whose hooks (and `carried`) run once.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from itertools import accumulate
from typing import Any

import mujoco
import torch

from labcli import refs
from labcli.envs import models
from labcli.envs.markers import Marker
from labcli.envs.mdp import (
    deployment,
    frames,
    object_model,
    robot_model,
    sensors,
    terrain_model,
)
from labcli.envs.mdp.config import Group, RobotTaskConfig, Term
from labcli.envs.mdp.motors import ExplicitMotors
from labcli.envs.mdp.robot import Robot
from labcli.envs.mdp.terrain_grid import TerrainGrid
from labcli.envs.models import ModelSource
from labcli.envs.random import EnvRandom
from labcli.envs.sim import Sim
from labcli.envs.task import Task, actuator_name
from labcli.errors import LabError

AXES = ("x", "y", "z")


def impl_of(term: Term) -> Any:
    return refs.resolve(type(term).impl, f"term {type(term).__name__}")


def _all_terms(cfg: RobotTaskConfig) -> list[tuple[str, Term]]:
    """Every term of `cfg`, with its key (`env.rewards.alive`)."""
    groups = ("commands", "observations", "rewards", "terminations", "events", "curriculum",
              *(["critic_extras"] if _critic_extras(cfg) else []))
    return [("env.actions", cfg.actions),
            *((f"env.{g}.{name}", t) for g in groups for name, t in getattr(cfg, g).terms()),
            *([("env.success", cfg.success)] if cfg.success is not None else [])]


def _critic_extras(cfg: RobotTaskConfig) -> list[Group]:
    """The critic's own terms' group where the critic reads them."""
    return [cfg.critic_extras] if cfg.critic_observations == "privileged" else []


class Built:
    """A term's code made for a task: `__call__`, and the optional hooks (no-ops if absent)."""

    def __init__(self, task: RobotTask, name: str, term: Term):
        code = impl_of(term)
        self.name, self.cfg = name, term
        if inspect.isclass(code):
            made = code(task, term)
            self.compute: Callable[[], torch.Tensor] = made
            self.made = made
            self.pre_physics = getattr(made, "pre_physics", None)
            self.after_step = getattr(made, "after_step", None)
            self.reset = getattr(made, "reset", None)
            self.metrics = getattr(made, "metrics", None)
            self.names: list[str] | None = getattr(made, "names", None)
        else:
            self.made = None
            self.compute = lambda: code(task, term)
            self.pre_physics = self.after_step = self.reset = self.metrics = None
            self.names = None


class RobotTask(Task):
    """Observations, rewards, terminations, events, actuation and success from `cfg`'s terms,
    over `self.robot` (labcli/envs/mdp/robot.py)."""

    cfg: RobotTaskConfig

    @classmethod
    def build_model(cls, cfg: RobotTaskConfig, source: ModelSource,  # type: ignore[override]
                    visual: bool = False) -> mujoco.MjModel:
        spec = models.load_spec(source)
        if not visual:
            models.drop_visual_meshes(spec)
        object_model.apply(spec, cfg.objects)
        if cfg.robot is not None:
            robot_model.apply(spec, cfg.robot)
        if cfg.terrain is not None:
            terrain_model.apply(spec, cfg.terrain)
        model = spec.compile()
        needed = [(key, s) for key, term in _all_terms(cfg)
                  for s in getattr(impl_of(term), "sensors", lambda m, t: [])(model, term)]
        if needed:
            for key, sensor in needed:
                sensors.check(model, sensor, key)
                sensors.add(spec, sensor)
            model = spec.compile()
        models.set_options(model, cfg)
        return model

    @classmethod
    def acts_each_physics_step(cls, cfg: RobotTaskConfig) -> bool:  # type: ignore[override]
        return cfg.robot is not None and any(g.explicit for g in cfg.robot.actuators.values())

    @classmethod
    def per_env_fields(cls, cfg: RobotTaskConfig) -> tuple[str, ...]:  # type: ignore[override]
        return tuple(sorted({field for _, term in cfg.events.terms()
                             for field in getattr(impl_of(term), "fields", ())}))

    def __init__(self, cfg: RobotTaskConfig, sim: Sim):
        super().__init__(cfg, sim)
        self.model = sim.model
        self._constants: dict[object, torch.Tensor] = {}
        self._shared: dict[object, Any] = {}
        self._terms_made = False
        self.num_envs = n = sim.num_envs
        self.robot = Robot(sim, cfg.root_body, cfg.default_pose)
        dev, dtype = sim.qpos.device, sim.qpos.dtype
        self.ones = torch.ones(n, dtype=dtype, device=dev)
        self.action = torch.zeros(n, sim.model.nu, dtype=dtype, device=dev)
        self.previous_action = torch.zeros_like(self.action)
        # Terms draw from the env's rng; the env sets its own before the first reset.
        self.rng = EnvRandom(n, dev)

        # Before the terms: a velocity command tells it the distance its curriculum asks for.
        self.terrain = (TerrainGrid(self, cfg.terrain, cfg.episode_length_s)
                        if cfg.terrain is not None else None)
        self.actuation = impl_of(cfg.actions)(self, cfg.actions)
        delay = getattr(self.actuation, "delay", None)
        # The action term's position targets: the servos' controls, or what explicit motors
        # turn into torques before each physics step (made before the terms: the gains' event
        # draws theirs).
        self.targets = sim.ctrl
        self.motors: ExplicitMotors | None = None
        if self.acts_each_physics_step(cfg):
            self.targets = torch.zeros_like(sim.ctrl)
            self.motors = ExplicitMotors(self, self.targets,
                                         delay.controls if delay is not None else None)
        self.action_names = [self.robot.joint_names[i] for i in range(sim.model.nu)]
        # Commands first: the terms made after them find theirs (`command(name)`).
        self._commands = {name: Built(self, name, t) for name, t in cfg.commands.terms()}
        self._obs = [Built(self, name, t) for name, t in cfg.observations.terms()]
        self._critic_extras = [Built(self, name, t) for group in _critic_extras(cfg)
                               for name, t in group.terms()]
        self._rewards = [Built(self, name, t) for name, t in cfg.rewards.terms()]
        terminations = [Built(self, name, t) for name, t in cfg.terminations.terms()]
        self._terminations = [b for b in terminations if not b.cfg.time_out]
        self.success_causes = frozenset(b.name for b in self._terminations if b.cfg.success)
        self._time_outs = [b for b in terminations if b.cfg.time_out]
        self._events = [Built(self, name, t) for name, t in cfg.events.terms()]
        # Env steps since the env was made, per env (all alike): what curricula go by.
        self.steps = torch.zeros(n, dtype=torch.long, device=dev)
        self._curriculum = [Built(self, name, t).compute for name, t in cfg.curriculum.terms()]
        self._success = (Built(self, "success", cfg.success) if cfg.success is not None
                         else None)
        every = [*self._commands.values(), *self._obs, *self._critic_extras, *self._rewards,
                 *self._terminations, *self._time_outs, *self._events,
                 *([self._success] if self._success else [])]
        self._terms_made = True
        shared = list(self._shared.values())
        self._pre_physics = [b.pre_physics for b in every if b.pre_physics is not None]
        self._after_step = [b.after_step for b in every if b.after_step is not None]
        # What terms share advances after the terms' own hooks: they read this step's state.
        self._after_step += [s.after_step for s in shared if hasattr(s, "after_step")]
        self._metrics = [(b.name, b.metrics) for b in every if b.metrics is not None]
        if self.terrain is not None:
            self._after_step.append(self.terrain.after_step)
            self._metrics.append(("terrain", self.terrain.metrics))
        # Start-up events (per-env physics) run once, at the env's first reset.
        self._startups = [b.compute.startup for b in self._events
                          if hasattr(b.compute, "startup")]
        # Events set the new state first; the other terms then remember it.
        self._event_resets = [b.reset for b in self._events if b.reset is not None]
        self._term_resets = [b.reset for b in every
                             if b.reset is not None and b not in self._events]
        self._term_resets += [s.reset for s in shared if hasattr(s, "reset")]
        self._carriers = [(b.name, b.made) for b in every if getattr(b.made, "carried", ())]
        if delay is not None:
            self.controls = delay.controls
            self._term_resets.append(delay.reset)
            self._carriers.append(("actions/delay", delay))
        if self.motors is not None:
            self.substep, self.controls = self.motors, None
            self._carriers.append(("actions/motors", self.motors))
            for name, net in self.motors.nets.items():
                self._term_resets.append(net.reset)
                self._carriers.append((f"actions/net/{name}", net))
        self._carriers += [(f"shared{i}", s) for i, s in enumerate(shared)
                           if getattr(s, "carried", ())]
        if self.terrain is not None:
            self._carriers.append(("terrain", self.terrain))
        if not self._obs:
            raise LabError("the task's config lists no observation terms",
                           "give env.observations at least one term")
        names = [self._names(b) for b in self._obs]
        self._obs_names = names
        self.observation_names = [name for built, term in zip(self._obs, names, strict=True)
                                  for name in frames.column_names(term, built.cfg.frames)]
        self.observation_units = {
            name: unit for built, columns in zip(self._obs, names, strict=True)
            for name, unit in zip(frames.column_names(columns, built.cfg.frames),
                                  (getattr(built.made, "units", None)
                                   or [type(built.cfg).unit] * len(columns)) * built.cfg.frames,
                                  strict=True)}
        self._obs_widths = [len(n) for n in names]
        terms = [b.cfg for b in self._obs]
        self._post = ObservationPost(self, terms, self._obs_widths)
        if self._post.bias is not None:
            self._term_resets.append(self._post.reset)
            self._carriers.append(("observations", self._post))
        self._frames = (frames.ObservationFrames(self, terms, self._obs_widths)
                        if any(t.frames > 1 or t.delay[1] > 0 for t in terms) else None)
        if self._frames is not None:
            self._term_resets.append(self._frames.reset)
            self._carriers.append(("observations/frames", self._frames))
        self._critic_extra_names = [self._names(b) for b in self._critic_extras]
        self._critic = (CriticObservations(self, terms, self._obs_widths, self._critic_extras,
                                           [len(n) for n in self._critic_extra_names])
                        if cfg.critic_observations != "policy" else None)
        if self._critic is not None and self._critic.frames is not None:
            self._term_resets.append(self._critic.frames.reset)
            self._carriers.append(("critic_observations/frames", self._critic.frames))
        # The histories that keep each step's frame at the next step's start.
        self._histories = [f for f in (self._frames, self._critic and self._critic.frames)
                           if f is not None]

    # the env's calls ---------------------------------------------------------------------------
    def apply_actions(self, actions: torch.Tensor) -> None:
        # The step starts here: what terms share is computed again inside it. On a GPU the step
        # replays as a CUDA graph, and a value cached before the capture would be replayed as a
        # constant (the progress reward's distance, read before the physics).
        self.robot.forget_derived()
        self.previous_action.copy_(self.action)
        self.action.copy_(actions)
        for history in self._histories:
            history.advance()
        for hook in self._pre_physics:
            hook()
        self.actuation(self.action, self.targets)

    def action_commands(self) -> list[dict[str, Any]]:
        commands = list(self.actuation.commands)
        for i in range(self.model.nu):
            motor = self.motors.describe(i) if self.motors is not None else None
            if motor is not None:
                commands[i] = (commands[i].replace("ctrl =", "target =", 1)
                               + f"; ctrl = the {motor['model']} motor's torque toward it")
        return [{"action": name, "actuator": actuator, "command": command,
                 "unit": self.action_units.get(name, "")}
                for name, actuator, command in zip(
                    self.action_names,
                    [actuator_name(self.model, i) for i in range(self.model.nu)],
                    commands, strict=True)]

    def update(self) -> None:
        self.robot.update()

    def observations(self) -> torch.Tensor:
        raw = torch.cat([b.compute() for b in self._obs], dim=1, out=self._post.raw)
        if self._critic is not None:  # before the policy's corruption, which works in place
            self._critic(raw)
        frame = self._post(raw)
        return frame if self._frames is None else self._frames(frame)

    def critic_observations(self) -> torch.Tensor | None:
        return None if self._critic is None else self._critic.value

    def reward_terms(self) -> dict[str, torch.Tensor]:
        return {b.name: b.compute() for b in self._rewards}

    def terminations(self) -> dict[str, torch.Tensor]:
        return {b.name: b.compute() for b in self._terminations}

    def deployment(self) -> dict[str, Any]:
        return deployment.describe(self)

    def time_outs(self) -> torch.Tensor | None:
        if not self._time_outs:
            return None
        return torch.stack([b.compute() for b in self._time_outs]).any(dim=0)

    def reset(self, mask: torch.Tensor, rng: EnvRandom) -> None:
        self.action.masked_fill_(mask[:, None], 0.0)
        self.previous_action.masked_fill_(mask[:, None], 0.0)
        self.robot.reset_to_default_pose(mask)
        while self._startups:
            self._startups.pop(0)()
        for hook in self._event_resets:
            hook(mask)
        if self.terrain is not None:  # onto the patches, before the terms note where they start
            self.terrain.reset(mask)
        # Terms' resets read the state's own views (root_pos...): the derived values are
        # recomputed once, by the env's update() that follows every reset.
        for hook in self._term_resets:
            hook(mask)

    def after_step(self) -> None:
        for hook in self._after_step:
            hook()
        if self._curriculum:
            self.steps += 1
            self._follow_curriculum()

    def weigh(self, weights: torch.Tensor) -> None:
        super().weigh(weights)
        self._follow_curriculum()

    def _follow_curriculum(self) -> None:
        for term in self._curriculum:
            term()

    def state(self) -> dict[str, torch.Tensor]:
        return {"action": self.action, "previous_action": self.previous_action,
                **({"steps": self.steps} if self._curriculum else {}),
                **{f"{owner}/{name}": getattr(made, name) for owner, made in self._carriers
                   for name in made.carried}}

    def upgraded_state(self, saved: dict[str, Any]) -> dict[str, Any]:
        for owner, made in self._carriers:
            if hasattr(made, "upgraded_state"):
                saved = made.upgraded_state(owner, saved)
        return saved

    def replayed(self) -> None:
        # Values shared per state (robot.per_state) that an eager read cached after the last
        # Python step would be read again as they were: a cube grasped since read as loose.
        self.robot.forget_derived()

    def state_restored(self) -> None:
        # The saved state has its start-up events' draws already: they must not run again.
        self._startups.clear()
        self._follow_curriculum()
        for _, made in self._carriers:
            if hasattr(made, "restored"):
                made.restored()

    def success(self, time_out: torch.Tensor) -> torch.Tensor:
        if self._success is None:
            return torch.zeros_like(time_out)
        return self._success.compute()

    def markers(self, env: int) -> list[Marker]:
        return [m for built in self._commands.values()
                for m in getattr(built.made, "markers", lambda e: [])(env)]

    def episode_metrics(self) -> dict[str, torch.Tensor]:
        return {f"{name}/{key}": value for name, metrics in self._metrics
                for key, value in metrics().items()}

    # helpers for terms -------------------------------------------------------------------------
    def command(self, name: str) -> Any:
        """The command term `name` of env.commands, as made (e.g. its `.command` tensor)."""
        built = self._commands.get(name)
        if built is None:
            raise LabError(f"a term reads command '{name}', which env.commands does not have",
                           f"name one of {sorted(self._commands) or 'no commands: add one'}")
        return built.made

    def base_height(self) -> torch.Tensor:
        """The root's height above the ground under it `[n]`: above the terrain's surface
        where the task has terrain, else above z = 0 (once per state)."""
        if self.terrain is None:
            return self.robot.root_height
        return self.robot.per_state("base_height", lambda: (
            self.robot.root_height - self.terrain.heights(self.robot.root_xy)))

    def shared(self, key: object, make: Callable[[], Any]) -> Any:
        """The object terms share under `key` (labcli/envs/mdp/feet.py), made by the first
        term that asks, in its `__init__`; its optional `after_step()` and `reset(mask)` run
        once per step and reset, after the terms' own."""
        made = self._shared.get(key)
        if made is None:
            if self._terms_made:
                raise RuntimeError(f"shared state {key!r} asked for after the terms were made: "
                                   "its hooks would never run; ask in the term's __init__")
            made = self._shared[key] = make()
        return made

    def constant(self, values: Sequence[float] | float) -> torch.Tensor:
        """A tensor of `values` on the sim's device and dtype, made on first use and kept (by
        value): a tensor built from Python numbers in the step would be a host-to-device copy
        on a GPU, which a CUDA graph cannot capture. Do not write into it."""
        key = tuple(values) if isinstance(values, Sequence) else values
        return self._kept(key, lambda: torch.as_tensor(
            values, dtype=self.sim.qpos.dtype, device=self.sim.qpos.device))

    def tiled(self, values: Sequence[float]) -> torch.Tensor:
        """`values` as a row per env, `[num_envs, len(values)]` (a `constant`, made once): an
        op with it runs as one flat loop, where broadcasting a short row steps through the envs
        one by one."""
        return self._kept(("tiled", *values), lambda: self.constant(values).expand(
            self.num_envs, len(values)).contiguous())

    def _kept(self, key: object, make: Callable[[], torch.Tensor]) -> torch.Tensor:
        made = self._constants.get(key)
        if made is None:
            made = self._constants[key] = make()
        return made

    def _names(self, built: Built) -> list[str]:
        width = built.compute().shape[1]
        if built.names is not None:
            return [f"{built.name}.{name}" for name in built.names]
        if width == 1:
            return [built.name]
        if width == len(self.robot.joint_names):
            return [f"{built.name}.{joint}" for joint in self.robot.joint_names]
        if width == 3:
            return [f"{built.name}.{axis}" for axis in AXES]
        return [f"{built.name}[{i}]" for i in range(width)]


class CriticObservations:
    """The policy's observation terms as the critic reads them (`critic_observations:
    noise_free`): each term's value without the policy's noise, bias and delay, clipped, scaled
    and framed as the policy's, in the same columns; with `privileged`, the critic's own terms
    (`extras`) after them, likewise without noise. `value` is the last state's, a tensor each
    call rewrites."""

    def __init__(self, task: RobotTask, terms: list[Any], widths: list[int],
                 extras: list[Built], extra_widths: list[int]):
        clean = [t.model_copy(update={"noise": 0.0, "bias": 0.0, "delay": (0, 0)})
                 for t in [*terms, *(b.cfg for b in extras)]]
        self.policy_width = sum(widths)
        ends = list(accumulate(extra_widths, initial=self.policy_width))
        self.extras = [(b.compute, slice(start, end))
                       for b, start, end in zip(extras, ends[:-1], ends[1:], strict=True)]
        self.post = ObservationPost(task, clean, [*widths, *extra_widths])
        self.frames = (frames.ObservationFrames(task, clean, [*widths, *extra_widths])
                       if any(t.frames > 1 for t in clean) else None)
        self.value = self.post.raw if self.frames is None else self.frames.out

    def __call__(self, raw: torch.Tensor) -> None:
        self.post.raw[:, :self.policy_width].copy_(raw)
        for compute, columns in self.extras:
            self.post.raw[:, columns].copy_(compute())
        frame = self.post(self.post.raw)
        self.value = frame if self.frames is None else self.frames(frame)


class ObservationPost:
    """Every term's bias, noise, scale and clip applied to the concatenated observations at
    once, as per-column vectors: a handful of ops per step however many terms there are. The
    biases are drawn per env at each episode's start (`reset`) and carried (`offset`)."""

    carried = ("offset",)

    def __init__(self, task: RobotTask, terms: list[Any], widths: list[int]):
        def column(values: list[float]) -> torch.Tensor:
            return task.tiled([v for v, w in zip(values, widths, strict=True) for _ in range(w)])

        self.task = task
        self.raw = torch.empty(task.num_envs, sum(widths), dtype=task.ones.dtype,
                               device=task.ones.device)
        noise = [t.noise if task.cfg.observation_noise else 0.0 for t in terms]
        self.noise = column(noise) if any(noise) else None
        self.draw = torch.empty_like(self.raw)
        bias = [t.bias if task.cfg.observation_noise else 0.0 for t in terms]
        self.bias = column(bias) if any(bias) else None
        self.offset = torch.zeros_like(self.raw)
        scale = [t.scale for t in terms]
        self.scale = column(scale) if any(v != 1.0 for v in scale) else None
        inf = float("inf")
        clips = [t.clip or (-inf, inf) for t in terms]
        self.clip = ((column([c[0] for c in clips]), column([c[1] for c in clips]))
                     if any(t.clip for t in terms) else None)

    def _within(self, half_width: torch.Tensor) -> torch.Tensor:
        """A draw uniform in (-half_width, half_width) per column, Isaac Lab's Unoise."""
        self.task.rng.uniform_(self.draw)
        return self.draw.mul_(2.0).sub_(1.0).mul_(half_width)

    def reset(self, mask: torch.Tensor) -> None:
        """New biases for the envs in `mask` (only where a term has one: `RobotTask`)."""
        torch.where(mask[:, None], self._within(self.bias), self.offset, out=self.offset)

    def __call__(self, obs: torch.Tensor) -> torch.Tensor:
        if self.bias is not None:
            obs.add_(self.offset)
        if self.noise is not None:
            obs.add_(self._within(self.noise))
        if self.clip is not None:  # Isaac Lab's order: noise, clip, scale
            torch.maximum(obs, self.clip[0], out=obs)
            torch.minimum(obs, self.clip[1], out=obs)
        if self.scale is not None:
            obs.mul_(self.scale)
        return obs
