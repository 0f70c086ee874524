"""An exported lab policy walking in plain MuJoCo: the loop a robot's controller runs.

    lab export onnx --last
    python examples/deploy_mujoco.py logs/rsl_rl/go1-flat/<run>/exported/policy.onnx --vx 0.5

NumPy, MuJoCo and onnxruntime only (no torch, no lab env): `labcli.sim2sim.PlainLoop` reads the
export's metadata (`policy.onnx.json`) and model (`policy.mjb`), builds each observation from the
robot's state as the metadata says (its kind, joints, clip and scale), runs the network, and
sends each action to its joint's position servo as offset + scale × action, holding it for the
metadata's decimation of physics steps (where the metadata names a motor model, `ideal_pd` or
`dc_motor`, the torque that model pulls toward that target, computed before each physics step). This script starts the robot standing in its default
pose, gives it one velocity command and prints, each second, the velocity it keeps; `--viewer`
shows it in MuJoCo's viewer in real time.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from labcli.sim2sim import PlainLoop


def standing(loop: PlainLoop) -> np.ndarray:
    """The model's first keyframe (else its reference pose), the joints at their defaults."""
    model = loop.model
    qpos = model.key_qpos[0].copy() if model.nkey else model.qpos0.copy()
    for joint in loop.meta["deployment"]["joints"]:
        qpos[model.jnt_qposadr[model.joint(joint["joint"]).id]] = joint["default_position"]
    return qpos


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("onnx", type=Path, help="an export's policy.onnx")
    p.add_argument("--vx", type=float, default=0.5, help="forward velocity command, m/s")
    p.add_argument("--vy", type=float, default=0.0, help="sideways velocity command, m/s")
    p.add_argument("--wz", type=float, default=0.0, help="yaw-rate command, rad/s")
    p.add_argument("--seconds", type=int, default=10)
    p.add_argument("--viewer", action="store_true")
    a = p.parse_args()

    loop = PlainLoop(a.onnx)
    loop.reset(standing(loop), np.zeros(loop.model.nv))
    command = np.array([a.vx, a.vy, a.wz])
    dt = loop.meta["timing"]["control_dt"]
    viewer = None
    if a.viewer:
        import mujoco.viewer

        viewer = mujoco.viewer.launch_passive(loop.model, loop.data)
    for second in range(1, a.seconds + 1):
        linear, yaw_rate = [], []
        for _ in range(round(1.0 / dt)):
            start = time.perf_counter()
            loop.step(command)
            lin, ang = loop.root_velocity_b()
            linear.append(lin[:2])
            yaw_rate.append(ang[2])
            if viewer is not None:
                viewer.sync()
                time.sleep(max(0.0, dt - (time.perf_counter() - start)))
        vx, vy = np.mean(linear, axis=0)
        print(f"t={second:3d} s  command ({a.vx:.2f}, {a.vy:.2f}, {a.wz:.2f})  "
              f"kept vx={vx:.2f} vy={vy:.2f} m/s, wz={np.mean(yaw_rate):.2f} rad/s, "
              f"base at z={loop.root_height():.2f} m", flush=True)


if __name__ == "__main__":
    main()
