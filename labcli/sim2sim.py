"""An exported robot policy driving plain MuJoCo: `mujoco.mj_step`, NumPy and onnxruntime, no
torch and no lab env code. Its observations are built from the export's metadata alone (each
term's kind, joints, clip and scale), its actions applied by the metadata's actuators, scales
and offsets, at the metadata's control rate. `lab sim2sim` runs it beside `lab play`; a
deployer reads it as the loop a robot runs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from labcli.mjtree import robot_free_joints

GRAVITY = np.array([0.0, 0.0, -1.0])
RAY_START = 5.0  # m above the root, where the height scan's rays start


@dataclass
class Trajectory:
    """One episode of the loop: after each control step, the root's linear velocity (xy) and
    yaw rate in its own frame, and the step at which a fall ended it (None: it did not)."""

    lin_vel_b: np.ndarray  # [steps, 2]
    yaw_rate: np.ndarray  # [steps]
    fell_at: int | None


class PlainLoop:
    """The policy at `onnx_path` with its metadata (`<onnx>.json`) on the MuJoCo model the
    export wrote beside it (`<onnx>.mjb`)."""

    def __init__(self, onnx_path: Path):
        import onnxruntime as ort

        self.meta: dict[str, Any] = json.loads(Path(f"{onnx_path}.json").read_text())
        self.model = mujoco.MjModel.from_binary_path(str(onnx_path.parent
                                                         / self.meta["mujoco_model"]))
        self.data = mujoco.MjData(self.model)
        self.session = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
        deployment = self.meta["deployment"]
        joints = deployment["joints"]
        self.actuators = np.array([self.model.actuator(j["actuator"]).id for j in joints])
        self.motors = _Motors(self.model, joints) if any("motor" in j for j in joints) else None
        self.scale = np.array([j["action_scale"] for j in joints])
        self.offset = np.array([j["action_offset"] for j in joints])
        self.default = {j["joint"]: j["default_position"] for j in joints}
        self.low, self.high = self.meta["output"]["range"]
        self.decimation = int(self.meta["timing"]["decimation"])
        free = robot_free_joints(self.model)
        if not free:
            raise ValueError("its robot is bolted to the world (no free joint), and the plain "
                             "loop replays robots with a floating base")
        self.root_q = int(self.model.jnt_qposadr[free[0]])
        self.root_v = int(self.model.jnt_dofadr[free[0]])
        self.terms = [self._reader(term) for term in deployment["observations"]]
        # Per term, its frames (oldest first) where the policy sees more than one; an episode's
        # first frame stands for those before it. Training's lag is not reproduced: a robot's
        # sensors bring their own.
        self.history = [term.get("history_length", 1) for term in deployment["observations"]]
        self.frames: list[np.ndarray | None] = [None] * len(self.terms)
        self.last_action = np.zeros(len(joints))

    def _reader(self, term: dict[str, Any]):
        """A function of the command that returns the term's value, clipped and scaled."""
        kind = term["kind"]
        joints = [name.split(".", 1)[1] for name in term["names"]]
        if kind in ("joint_pos_rel", "joint_vel_rel"):
            ids = [self.model.joint(j).id for j in joints]
            if kind == "joint_pos_rel":
                adr, source = self.model.jnt_qposadr[ids], self.data.qpos
                default = np.array([self.default[j] for j in joints])
            else:
                adr, source, default = self.model.jnt_dofadr[ids], self.data.qvel, 0.0
            raw = lambda command: source[adr] - default  # noqa: E731
        elif kind == "height_scan":
            points = np.array([[float(v) for v in name.split(".", 1)[1].split(",")]
                               for name in term["names"]])
            offset = term["settings"]["offset"]
            raw = lambda command: self._scan(points) - offset  # noqa: E731
        elif kind == "projected_gravity" and term.get("settings", {}).get("site"):
            # An IMU's site on the root: its frame turned by the site's rotation in the root.
            # (data.site_xmat after mj_step holds the pose before its last integration.)
            turned = np.zeros(9)
            mujoco.mju_quat2Mat(turned, self.model.site(term["settings"]["site"]).quat)
            imu = turned.reshape(3, 3)
            raw = lambda command: imu.T @ self.root_rotation().T @ GRAVITY  # noqa: E731
        else:
            raw = {"base_lin_vel": lambda command: self.root_rotation().T @ self._root_vel()[:3],
                   "base_ang_vel": lambda command: self._root_vel()[3:],
                   "projected_gravity": lambda command: self.root_rotation().T @ GRAVITY,
                   "generated_commands": lambda command: command,
                   "last_action": lambda command: self.last_action}.get(kind)
            if raw is None:
                raise ValueError(f"observation term '{term['term']}' ({kind}) has no reading in "
                                 "plain MuJoCo here")
        low, high = term["clip"] or (-np.inf, np.inf)
        return lambda command: np.clip(raw(command), low, high) * term["scale"]

    def _scan(self, points: np.ndarray) -> np.ndarray:
        """The root's height above the ground under each point (x, y in the root's frame,
        turned by its yaw alone): MuJoCo's ray from above, past the robot's own geoms."""
        rotation = self.root_rotation()
        yaw = np.arctan2(rotation[1, 0], rotation[0, 0])
        cos, sin = np.cos(yaw), np.sin(yaw)
        root = self.data.qpos[self.root_q:self.root_q + 3]
        down, geom = np.array([0.0, 0.0, -1.0]), np.zeros(1, np.int32)
        heights = np.empty(len(points))
        for i, (px, py) in enumerate(points):
            start = np.array([root[0] + cos * px - sin * py, root[1] + sin * px + cos * py,
                              root[2] + RAY_START])
            while True:  # the world body's geoms are the ground; a robot's geom is passed
                hit = mujoco.mj_ray(self.model, self.data, start, down, None, 1, -1, geom)
                if hit < 0 or self.model.geom_bodyid[geom[0]] == 0:
                    break
                start = start + down * (hit + 1e-6)
            heights[i] = root[2] - (start[2] - hit if hit >= 0 else -np.inf)
        return heights

    def root_rotation(self) -> np.ndarray:
        """The root's orientation as a rotation matrix (its frame's axes in the world's)."""
        matrix = np.zeros(9)
        mujoco.mju_quat2Mat(matrix, self.data.qpos[self.root_q + 3:self.root_q + 7])
        return matrix.reshape(3, 3)

    def root_height(self) -> float:
        return float(self.data.qpos[self.root_q + 2])

    def _root_vel(self) -> np.ndarray:
        # A free joint's linear velocity is in the world frame, its angular one in its own.
        return self.data.qvel[self.root_v:self.root_v + 6]

    def root_velocity_b(self) -> tuple[np.ndarray, np.ndarray]:
        """The root's linear and angular velocity in its own frame."""
        velocity = self._root_vel()
        return self.root_rotation().T @ velocity[:3], velocity[3:].copy()

    def observe(self, command: np.ndarray) -> np.ndarray:
        """The policy's input at this control step (each call is the next step's)."""
        for i, (read, length) in enumerate(zip(self.terms, self.history, strict=True)):
            frame = read(command)
            kept = self.frames[i]
            self.frames[i] = (np.tile(frame, (length, 1)) if kept is None
                              else np.vstack([kept[1:], frame]))
        return np.concatenate([f.ravel() for f in self.frames]).astype(np.float32)

    def step(self, command: np.ndarray) -> None:
        """One control step: observe, act, and hold the actuators' targets for `decimation`
        physics steps."""
        action = self.session.run(None, {"obs": self.observe(command)[None]})[0][0]
        self.last_action = np.clip(action.astype(np.float64), self.low, self.high)
        target = self.offset + self.scale * self.last_action
        for _ in range(self.decimation):
            self.data.ctrl[self.actuators] = (target if self.motors is None
                                              else self.motors(target, self.data))
            mujoco.mj_step(self.model, self.data)

    def reset(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Put the robot in the state (`qpos`, `qvel`), its last action zero."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:], self.data.qvel[:] = qpos, qvel
        mujoco.mj_forward(self.model, self.data)
        self.last_action = np.zeros_like(self.last_action)
        self.frames = [None] * len(self.terms)

    def run(self, qpos: np.ndarray, qvel: np.ndarray, commands: np.ndarray, fell) -> Trajectory:
        """An episode from the state (`qpos`, `qvel`) under `commands[t]` at step t, until they
        run out or `fell(model, data)` says the robot fell."""
        self.reset(qpos, qvel)
        lin, yaw = [], []
        for t, command in enumerate(commands):
            self.step(command)
            linear, angular = self.root_velocity_b()
            lin.append(linear[:2])
            yaw.append(angular[2])
            if fell(self.model, self.data):
                return Trajectory(np.array(lin), np.array(yaw), t)
        return Trajectory(np.array(lin), np.array(yaw), None)


class _Motors:
    """The export's motor models (`deployment.joints[i].motor`), each physics step: a PD law's
    torque toward the target, within the motor's torque-speed line and effort limit, as a
    robot's motor driver computes it; joints without a model get their target as it is."""

    def __init__(self, model: mujoco.MjModel, joints: list[dict[str, Any]]):
        if any(j.get("motor", {}).get("model") == "mlp" for j in joints):
            raise ValueError("its joints are driven by a learned actuator net (motor model "
                             "mlp), which the plain loop does not run")
        explicit = [i for i, j in enumerate(joints) if "motor" in j]
        self.explicit = np.array(explicit)
        ids = [model.joint(joints[i]["joint"]).id for i in explicit]
        self.qadr, self.dadr = model.jnt_qposadr[ids], model.jnt_dofadr[ids]
        motors = [joints[i]["motor"] for i in explicit]
        self.kp = np.array([m["stiffness"] for m in motors])
        self.kd = np.array([m["damping"] for m in motors])
        self.effort = np.array([joints[i]["effort_limit"] for i in explicit])
        self.saturation = np.array([m.get("saturation_effort") or e
                                    for m, e in zip(motors, self.effort, strict=True)])
        self.velocity = np.array([m.get("velocity_limit") or np.inf for m in motors])

    def __call__(self, target: np.ndarray, data: mujoco.MjData) -> np.ndarray:
        q, qd = data.qpos[self.qadr], data.qvel[self.dadr]
        torque = self.kp * (target[self.explicit] - q) - self.kd * qd
        speed = qd / self.velocity
        high = np.minimum(np.maximum(self.saturation * (1.0 - speed), 0.0), self.effort)
        low = np.maximum(np.minimum(self.saturation * (-1.0 - speed), 0.0), -self.effort)
        ctrl = target.copy()
        ctrl[self.explicit] = np.clip(torque, low, high)
        return ctrl


def tracking_errors(commands: np.ndarray, lin_vel_b: np.ndarray, yaw_rate: np.ndarray,
                    step_dt: float, window_s: float = 0.0) -> tuple[float, float]:
    """An episode's mean xy and yaw-rate tracking errors: each step's command (vx, vy, wz)
    against the velocity after the step, averaged over `window_s` first where it is set (the
    average starting from rest: the first error is the command)."""
    lin = commands[:len(lin_vel_b), :2] - lin_vel_b
    yaw = commands[:len(yaw_rate), 2] - yaw_rate
    if window_s > 0.0:
        weight = min(1.0, step_dt / window_s)
        averaged = commands[0].copy()
        smooth = np.empty((len(lin), 3))
        for t in range(len(lin)):
            averaged += weight * (np.append(lin[t], yaw[t]) - averaged)
            smooth[t] = averaged
        lin, yaw = smooth[:, :2], smooth[:, 2]
    return float(np.linalg.norm(lin, axis=1).mean()), float(np.abs(yaw).mean())
