"""What a deployer wires around an exported robot policy besides the network, read from the task
as built: each action's joint, actuator, default position, PD gains, limits, scale and offset
(and the motor model that turns its target into a torque, where lab computes it);
each observation term's columns, scale, clip, training noise, frames and lag; each command's
fields and ranges; the motors' latency it was trained under. `lab export` writes it into the
policy's metadata (and, for ONNX, also under the keys mjlab's exports use).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import mujoco

from labcli.envs.task import actuator_name

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask

# Where each observation term's value comes from on a robot: its own sensors and state, the
# commands it is given, or the policy's last output.
COMMAND_TERMS = {"generated_commands"}
ACTION_TERMS = {"last_action"}


def describe(task: RobotTask) -> dict[str, Any]:
    return {"joints": _joints(task), "observations": _observations(task),
            "commands": _commands(task), "actuator_delay_s": _delay(task)}


def _delay(task: RobotTask) -> list[float] | None:
    """The motors' latency the policy was trained under, (low, high) seconds; None: none."""
    delay = task.cfg.actions.delay
    return None if delay is None else [n * task.model.opt.timestep for n in delay]


def _joints(task: RobotTask) -> list[dict[str, Any]]:
    """In action order: an action i drives actuator i (`task.action_names`)."""
    model, act = task.model, task.actuation
    scale = act.scale[0].tolist()
    offset = act.offset[0].tolist() if act.offset is not None else [0.0] * model.nu
    default = task.robot.default_joint_pos[0].tolist()
    binary = act.binary
    rows = []
    for i, name in enumerate(task.action_names):
        # A motor model's law (labcli.envs.mdp.motors): the MjModel's actuator is then a plain
        # motor that takes the torque lab computed toward the action's target.
        motor = task.motors.describe(i) if task.motors is not None else None
        kp, kd = (motor["stiffness"], motor["damping"]) if motor else _gains(model, i)
        rows.append({
            "joint": name, "actuator": actuator_name(model, i), "default_position": default[i],
            "stiffness": kp, "damping": kd, "effort_limit": _effort_limit(model, i),
            "action_scale": scale[i], "action_offset": offset[i],
            "command": "position target" if kp is not None or motor else "torque",
            **({"motor": motor} if motor else {}),
            # A gripper's: its target is `open` where the action is >= 0, else `close`.
            **({"binary": {"open": binary.cfg.open, "close": binary.cfg.close}}
               if binary is not None and i in binary.actuators else {})})
    return rows


def _gains(model: mujoco.MjModel, i: int) -> tuple[float | None, float | None]:
    """A position servo's (kp, kd): MuJoCo's fixed gain and affine bias (0, -kp, -kd); None
    for a motor, whose command is the torque itself."""
    fixed = model.actuator_gaintype[i] == mujoco.mjtGain.mjGAIN_FIXED
    affine = model.actuator_biastype[i] == mujoco.mjtBias.mjBIAS_AFFINE
    if not (fixed and affine):
        return None, None
    return float(model.actuator_gainprm[i, 0]), float(-model.actuator_biasprm[i, 2])


def _effort_limit(model: mujoco.MjModel, i: int) -> float | None:
    """The actuator's force range, else its joint's actuator-force range; None if neither."""
    if model.actuator_forcelimited[i]:
        return float(model.actuator_forcerange[i, 1])
    joint = model.actuator_trnid[i, 0]
    if model.jnt_actfrclimited[joint]:
        return float(model.jnt_actfrcrange[joint, 1])
    return None


def _observations(task: RobotTask) -> list[dict[str, Any]]:
    """Per term, in input order: the term's columns, the names of one frame's, and what the
    task did to its raw value, in that order: in training a bias per episode and noise per step
    (each uniform in ±its value), clip, scale; then its frames, `history_length` of them oldest
    first (the columns hold them one after another), and in training their lag in control
    steps, drawn per episode from `training_delay_steps`."""
    rows, start = [], 0
    for built, names in zip(task._obs, task._obs_names, strict=True):
        cfg = built.cfg
        function = type(cfg).impl.rsplit(":", 1)[1]
        width = len(names) * cfg.frames
        rows.append({
            # What it measures (lab's term function: Isaac Lab's names), whatever its name.
            "term": built.name, "kind": function, "columns": [start, start + width],
            "names": names,
            "source": ("command" if function in COMMAND_TERMS else
                       "last action" if function in ACTION_TERMS else "robot"),
            "scale": cfg.scale, "clip": list(cfg.clip) if cfg.clip else None,
            "training_noise": cfg.noise, "training_bias": cfg.bias,
            "history_length": cfg.frames, "training_delay_steps": list(cfg.delay),
            # The term's own numbers (a height scan's grid and offset), to compute it alike.
            **({"settings": own} if (own := cfg.model_dump(
                mode="json", exclude={"scale", "clip", "noise", "bias", "history_length",
                                      "delay"})) else {})})
        start += width
    return rows


def _commands(task: RobotTask) -> list[dict[str, Any]]:
    """Each command term's fields and the ranges training drew them from."""
    rows = []
    for name, built in task._commands.items():
        fields = getattr(built.made, "names", None) or []
        ranges = {f: list(getattr(built.cfg, f)) for f in fields
                  if isinstance(getattr(built.cfg, f, None), tuple)}
        rows.append({"name": name, "fields": fields, "ranges": ranges})
    return rows


def mjlab_keys(deployment: dict[str, Any], observation_names: list[str]) -> dict[str, str]:
    """The deployment in the metadata keys of mjlab's ONNX exports, each a comma-separated list
    (joint order = action order; a motor's gains are 0)."""
    joints = deployment["joints"]
    terms = deployment["observations"]

    def csv(values: list[Any]) -> str:
        return ",".join(str(v) for v in values)

    def clip(term: dict[str, Any]) -> list[float]:
        return term["clip"] or [-math.inf, math.inf]

    return {
        "joint_names": csv([j["joint"] for j in joints]),
        "joint_stiffness": csv([j["stiffness"] or 0.0 for j in joints]),
        "joint_damping": csv([j["damping"] or 0.0 for j in joints]),
        "default_joint_pos": csv([j["default_position"] for j in joints]),
        "action_scale": csv([j["action_scale"] for j in joints]),
        "command_names": csv([c["name"] for c in deployment["commands"]]),
        "observation_names": csv([t["term"] for t in terms]),
        "observation_terms_scale": csv([t["scale"] for t in terms]),
        "observation_terms_clip": csv([v for t in terms for v in clip(t)]),
        "observation_columns": csv(observation_names),
    }
