"""`lab sim2sim`: a run's ONNX export driving plain MuJoCo (`labcli.sim2sim`) beside lab's own
env (`lab play`'s: its checkpoint, noise, pushes and motor latency off), from the same start
states under the same commands. Each side's episodes are judged by the task's own rule (the
time-out reached, no termination, mean tracking errors under its success bounds); the check
fails when the success rates differ by more than a tolerance: an export whose metadata misleads
a deployer (a joint out of order, a wrong scale) walks in lab and falls in plain MuJoCo.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import torch

from labcli.envs.env import EPISODE
from labcli.envs.mdp import config as c
from labcli.envs.mdp import names
from labcli.errors import LabError
from labcli.runs import play, rundir
from labcli.sim2sim import PlainLoop, tracking_errors

TOLERANCE = 0.1  # of the success rate: 2 of 16 episodes, 6 of 64
# Of the first observation, lab's and the metadata's of the same state: float32's rounding.
# A height scan is read by lab from a 5 cm map of the terrain and here by MuJoCo's rays, which
# differ by a whole step within 5 cm of an edge: its median difference is held to 1 cm.
OBS_TOLERANCE = 1e-4
SCAN_TOLERANCE = 0.01
# Of the joints' positions after the first control step (rad): lab's per-env randomization of
# masses and friction moved a Go1's by up to 0.005; an action sent to the wrong joint, by 0.3.
STEP_TOLERANCE = 0.05


@dataclass(frozen=True)
class Side:
    success: float
    falls: int
    lin_vel_error: float
    yaw_rate_error: float


@dataclass(frozen=True)
class CheckResult:
    export: Path
    episodes: int
    lab: Side
    plain: Side
    tolerance: float
    # The largest difference between lab's first observation and the one built from the
    # metadata in the same state, over its tolerance (passed at most 1), and its input.
    obs_diff: float
    obs_worst: str
    # The same of the joints' positions after the first control step.
    step_diff: float
    step_worst: str

    @property
    def passed(self) -> bool:
        return (self.obs_diff <= 1.0 and self.step_diff <= STEP_TOLERANCE
                and abs(self.lab.success - self.plain.success) <= self.tolerance)


@dataclass(frozen=True)
class Rule:
    """The task's success rule, read from its config: bounds, the errors' window and the step."""

    lin_vel_error: float
    ang_vel_error: float
    window_s: float
    step_dt: float

    def judge(self, commands: np.ndarray, lin: np.ndarray, yaw: np.ndarray,
              timed_out: bool) -> tuple[bool, float, float]:
        lin_error, yaw_error = tracking_errors(commands, lin, yaw, self.step_dt, self.window_s)
        ok = timed_out and lin_error < self.lin_vel_error and yaw_error < self.ang_vel_error
        return ok, lin_error, yaw_error


def check(*, run_dir: Path | None = None, task: str | None = None,
          framework: str | None = None, logs_dir: Path | None = None, episodes: int = 16,
          seed: int = 0, tolerance: float = TOLERANCE) -> CheckResult:
    if episodes <= 0:
        raise LabError(f"--episodes must be a positive integer, got {episodes}")
    run = (rundir.open_run(run_dir) if run_dir is not None
           else rundir.latest(logs_dir or rundir.default_logs_dir(), task, framework))
    export = run.dir / rundir.EXPORTED / "policy.onnx"
    meta_path = Path(f"{export}.json")
    if not meta_path.is_file():
        raise LabError(f"{run.dir} has no ONNX export", f"run `lab export onnx --run {run.dir}` "
                       "first")
    meta = json.loads(meta_path.read_text())
    if "deployment" not in meta or "mujoco_model" not in meta:
        raise LabError(f"{meta_path.name} describes no robot deployment (task "
                       f"'{meta.get('task')}')", "sim2sim checks robot tasks' exports, made "
                       "by this version of `lab export onnx`")
    try:
        loop = PlainLoop(export)
    except ValueError as exc:
        raise LabError(f"{export}: {exc}", "sim2sim computes velocity tasks' observation "
                       "terms and the ideal_pd and dc_motor motor models") from None
    # The plain loop sends each control and reads each sensor at once: lab's side too,
    # whatever latency the policy was trained under (the export's `actuator_delay_s` and
    # `training_delay_steps`).
    unlagged = [f"env.observations.{term['term']}.delay=[0,0]"
                for term in meta["deployment"]["observations"]
                if any(term.get("training_delay_steps", ()))]
    loaded = play.load(checkpoint=run.dir / meta["checkpoint"], num_envs=episodes,
                       overrides=["env.actions.delay=null", *unlagged])
    try:
        task = loaded.env.task
        rule = _rule(task)
        fell = _fall(task, loop)
        first, start, stepped, commands, lab_lengths, lab_success, lab_fell, lin, yaw = _record(
            loaded, meta, seed)
    finally:
        loaded.env.close()
    steps = commands.shape[1]
    built = np.stack([_first_observation(loop, start[i], commands[i, 0])
                      for i in range(episodes)])
    obs_diff, obs_worst = _worst_input(meta, np.abs(built - first))
    joints = [j["joint"] for j in meta["deployment"]["joints"]]
    adr = loop.model.jnt_qposadr[[loop.model.joint(j).id for j in joints]]
    moved = []
    for i in range(episodes):
        loop.reset(*start[i])
        loop.step(commands[i, 0])
        moved.append(np.abs(loop.data.qpos[adr] - stepped[i][adr]))
    step_diff = np.max(moved, axis=0)
    step_worst = int(step_diff.argmax())
    lab_rows, plain_rows = [], []
    for i in range(episodes):
        n = lab_lengths[i]
        lab_rows.append((lab_success[i], lab_fell[i],
                         *rule.judge(commands[i], lin[i, :n], yaw[i, :n], n == steps)[1:]))
        # Lab's commands end with its episode: an episode lab ended early ends there here too.
        traj = loop.run(*start[i], commands[i, :n], fell)
        done = traj.fell_at is None and n == steps
        ok, lin_error, yaw_error = rule.judge(commands[i], traj.lin_vel_b, traj.yaw_rate, done)
        plain_rows.append((ok, traj.fell_at is not None, lin_error, yaw_error))
    return CheckResult(export, episodes, _side(lab_rows), _side(plain_rows), tolerance,
                       obs_diff, obs_worst,
                       float(step_diff[step_worst]), joints[step_worst])


def _first_observation(loop: PlainLoop, state: tuple[np.ndarray, np.ndarray],
                       command: np.ndarray) -> np.ndarray:
    loop.reset(*state)
    return loop.observe(command)


def _worst_input(meta: dict, diff: np.ndarray) -> tuple[float, str]:
    """The largest of the inputs' differences `[episodes, inputs]` over their tolerances (a
    height scan's median over its points and episodes), and which input it is."""
    names = [o["name"] for o in meta["input"]["observations"]]
    worst = (0.0, names[0])
    for term in meta["deployment"]["observations"]:
        a, b = term["columns"]
        if term["kind"] == "height_scan":
            found = (float(np.median(diff[:, a:b])) / SCAN_TOLERANCE, f"{term['term']} (median)")
        else:
            column = a + int(diff[:, a:b].max(axis=0).argmax())
            found = (float(diff[:, column].max()) / OBS_TOLERANCE, names[column])
        worst = max(worst, found)
    return worst


def _side(rows: list[tuple[bool, bool, float, float]]) -> Side:
    ok, falls, lin, yaw = zip(*rows, strict=True)
    return Side(float(np.mean(ok)), int(sum(falls)), float(np.mean(lin)), float(np.mean(yaw)))


def _rule(task) -> Rule:
    success = task.cfg.success
    if not isinstance(success, c.TrackedCommand):
        raise LabError(f"task '{task.cfg.__class__.__name__}' does not judge episodes by a "
                       "tracked velocity command", "sim2sim checks velocity tasks")
    command = task.command(success.command)
    return Rule(success.lin_vel_error, success.ang_vel_error,
                getattr(command.cfg, "error_window", 0.0), task.step_dt)


def _fall(task, loop: PlainLoop) -> Callable[[mujoco.MjModel, mujoco.MjData], bool]:
    """The task's terminations (not its time-outs) as a test of the loop's MuJoCo state."""
    model, tests = loop.model, []
    for name, term in task.cfg.terminations.terms():
        if term.time_out:
            continue
        if isinstance(term, c.IllegalContact):
            bodies = set(names.resolve(model, "body", term.bodies))
            tests.append(lambda m, d, b=bodies, f=term.threshold: _touches(m, d, b, f))
        elif isinstance(term, c.BadOrientation):
            tests.append(lambda m, d, a=term.limit_angle: _tilt(loop) > a)
        elif isinstance(term, c.BaseHeightBelow):
            tests.append(lambda m, d, h=term.minimum_height: loop.root_height() < h)
        else:
            raise LabError(f"termination '{name}' has no plain-MuJoCo test here",
                           "sim2sim knows illegal contacts, bad orientation and base height")
    return lambda m, d: any(test(m, d) for test in tests)


def _touches(model: mujoco.MjModel, data: mujoco.MjData, bodies: set[int],
             threshold: float) -> bool:
    """Whether any of `bodies` is pushed by its contacts with more than `threshold` N."""
    total = dict.fromkeys(bodies, 0.0)
    force = np.zeros(6)
    for i in range(data.ncon):
        contact = data.contact[i]
        touched = {int(model.geom_bodyid[contact.geom1]), int(model.geom_bodyid[contact.geom2])}
        for body in touched & bodies:
            mujoco.mj_contactForce(model, data, i, force)
            total[body] += abs(force[0])
    return any(value > threshold for value in total.values())


def _tilt(loop: PlainLoop) -> float:
    """The angle of the root's z axis from the world's up."""
    return math.acos(max(-1.0, min(1.0, loop.root_rotation()[2, 2])))


def _record(loaded, meta: dict, seed: int):
    """lab's env under its policy until every env ended its first episode: each env's start
    state and its joints after the first step, the command in each step's observation, the
    episode's length, success and whether a termination ended it, and the root's velocity
    after each step."""
    env, policy = loaded.env, loaded.policy
    terms = {t["kind"]: t for t in meta["deployment"]["observations"]}
    missing = {"generated_commands", "base_lin_vel", "base_ang_vel"} - set(terms)
    if missing:
        raise LabError(f"the policy observes no {', '.join(sorted(missing))}", "sim2sim reads "
                       "the commands and the root's velocities from lab's observations")
    steps = int(round(env.task.cfg.episode_length_s / env.task.step_dt))
    obs, _ = env.reset(seed=seed)
    first = obs.cpu().double().numpy().copy()
    sim = env.task.sim
    start = list(zip(sim.qpos.cpu().double().numpy().copy(), sim.qvel.cpu().double().numpy().copy(),
                     strict=True))
    n = env.num_envs
    commands, lin, yaw = np.zeros((n, steps, 3)), np.zeros((n, steps, 2)), np.zeros((n, steps))
    lengths, success, fell = np.full(n, steps), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    ended = np.zeros(n, dtype=bool)
    for t in range(steps):
        commands[:, t] = _column(obs, terms["generated_commands"])
        with torch.inference_mode():
            obs, _, terminated, truncated, info = env.step(policy(obs))
        if t == 0:
            stepped = sim.qpos.cpu().double().numpy().copy()
        done = (terminated | truncated).cpu().numpy()
        after = obs.clone()
        if done.any() and "final_obs" in info:
            after[torch.as_tensor(done)] = info["final_obs"][torch.as_tensor(done)]
        lin[:, t] = _column(after, terms["base_lin_vel"])[:, :2]
        yaw[:, t] = _column(after, terms["base_ang_vel"])[:, 2]
        new = done & ~ended
        lengths[new] = t + 1
        success[new] = info[EPISODE]["success"].cpu().numpy()[new]
        fell[new] = terminated.cpu().numpy()[new]
        ended |= done
        if ended.all():
            break
    return first, start, stepped, commands, lengths, success, fell, lin, yaw


def _column(obs: torch.Tensor, term: dict) -> np.ndarray:
    a, b = term["columns"]
    return obs[:, a:b].cpu().double().numpy() / term["scale"]
