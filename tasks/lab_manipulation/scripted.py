"""A scripted grasp of yam-lift's cube: the arm's joint targets from the inverse kinematics of
its `pinch` site, as the task's actions. The tests lift the cube with it on both backends;
bench/replay_diff.py replays it in mjlab's Lift-Cube-Yam to compare the two physics step by
step."""

import math

import mujoco
import numpy as np
import torch

ARM = [f"joint{i}" for i in range(1, 7)]
# The cube's free joint after the arm's 6 joints and 2 fingers: position, then orientation.
CUBE_POS, CUBE_QUAT = slice(8, 11), slice(11, 15)
SETTLE_STEPS = 25  # env steps for a cube dropped from up to 3 cm to come to rest


def pinch_down_at(model: mujoco.MjModel, qpos: np.ndarray, pos: np.ndarray,
                  yaw: float) -> np.ndarray:
    """The arm's joint angles that put the `pinch` site at `pos`, pointing down, its fingers
    closing across the cube's faces (the site's y axis along the cube's yaw): damped least
    squares on MuJoCo's site Jacobian, within the joints' ranges."""
    data, site = mujoco.MjData(model), model.site("pinch").id
    data.qpos[:] = qpos
    arm = [model.joint(j).qposadr[0] for j in ARM]
    low, high = model.jnt_range[:6].T
    for _ in range(400):
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        rot = data.site_xmat[site].reshape(3, 3)
        across = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        across = across if across @ rot[:, 1] >= 0 else -across
        down = np.array([0.0, 0.0, -1.0])
        goal = np.column_stack([np.cross(across, down), across, down])
        error, turn = np.zeros(6), np.zeros(4)
        error[:3] = pos - data.site_xpos[site]
        mujoco.mju_mat2Quat(turn, (goal @ rot.T).ravel())
        mujoco.mju_quat2Vel(error[3:], turn, 1.0)
        if np.abs(error).max() < 1e-7:
            break
        jac_pos, jac_rot = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jac_pos, jac_rot, site)
        jac = np.vstack([jac_pos, jac_rot])[:, arm]
        step = jac.T @ np.linalg.solve(jac @ jac.T + 1e-4 * np.eye(6), error)
        data.qpos[arm] = np.clip(data.qpos[arm] + 0.5 * step, low, high)
    if np.abs(error).max() >= 1e-5:
        raise ValueError(f"no joint angles within range put the pinch at {pos.tolist()}, "
                         f"pointing down across a yaw of {yaw:.3f}")
    return data.qpos[arm].copy()


def holding(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """Each arm servo's target less its joint's angle (rad) that holds the arm still at `qpos`
    against the gravity its model does not compensate: the joints' gravity torques, less
    their compensation, over the servos' stiffness (0 where the links are weightless)."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    dofs = [model.joint(j).dofadr[0] for j in ARM]
    servos = [next(a for a in range(model.nu) if model.actuator_trnid[a, 0] == model.joint(j).id)
              for j in ARM]
    return (data.qfrc_bias - data.qfrc_gravcomp)[dofs] / model.actuator_gainprm[servos, 0]


def settle(env) -> None:
    """The cubes, dropped from up to 3 cm at reset, come to rest on the floor."""
    for _ in range(SETTLE_STEPS):
        env.step(torch.zeros(env.num_envs, 7, device=env.sim.qpos.device))


def plan(env, heights: list[float], grips: list[float]) -> list[torch.Tensor]:
    """The actions that put each env's pinch over its cube where it rests, `heights` (m) over
    its centre and the fingers at `grips` (m), one of each a step, the pinch's y axis across
    the cube's faces, the arm's targets raised to hold it against any gravity its model does
    not compensate. Each step's joint targets start from the last ones (small steps of the
    hand)."""
    model, task = env.sim.model, env.task
    scales = np.array([g.scale(2.0, 2.0) for g in task.cfg.robot.actuators.values()])
    default = task.robot.default_joint_pos[0].double().cpu().numpy()
    qpos = env.sim.qpos.double().cpu().numpy().copy()  # a copy: planning must not move the arm
    cubes = qpos[:, CUBE_POS].copy()
    w, z = qpos[:, CUBE_QUAT][:, 0], qpos[:, CUBE_QUAT][:, 3]
    yaws = 2.0 * np.arctan2(z, w)
    arm = [model.joint(j).qposadr[0] for j in ARM]
    actions = []
    for height, grip in zip(heights, grips, strict=True):
        rows = []
        for i in range(env.num_envs):
            qpos[i, arm] = pinch_down_at(model, qpos[i], cubes[i] + [0, 0, height], yaws[i])
            targets = qpos[i, arm] + holding(model, qpos[i])
            rows.append((np.append(targets, grip) - default[:7]) / scales)
        actions.append(torch.tensor(np.stack(rows), dtype=torch.float32))
    return actions


def grasp(env) -> list[torch.Tensor]:
    """A scripted grasp: the pinch 12 cm over the cube with the gripper open, down to it along
    a straight line, the gripper closed, up 10 cm."""
    heights = ([0.12] * 40 + np.linspace(0.12, 0.0, 50).tolist() + [0.0] * 80
               + np.linspace(0.0, 0.1, 100).tolist() + [0.1] * 20)
    grips = [0.0375] * 100 + [0.0] * 190  # open, then closed from 10 steps at the cube
    return plan(env, heights, grips)
