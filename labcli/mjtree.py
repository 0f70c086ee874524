"""MuJoCo models' kinematic trees: which free joints are a robot's floating base, and which
belong to the free bodies it handles (a cube to lift); which bodies lie under a body. MuJoCo
only, for the envs and for the plain-MuJoCo loop alike."""

from __future__ import annotations

import mujoco

FREE = mujoco.mjtJoint.mjJNT_FREE


def robot_free_joints(model: mujoco.MjModel) -> list[int]:
    """The free joints of the trees that hold actuated joints: the robot's floating base, not
    a free body it handles. A model without actuators (a passive body) is all robot."""
    free = [j for j in range(model.njnt) if model.jnt_type[j] == FREE]
    if not model.nu:
        return free
    roots = {int(model.body_rootid[model.jnt_bodyid[model.actuator_trnid[a, 0]]])
             for a in range(model.nu)
             if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT}
    return [j for j in free if int(model.body_rootid[model.jnt_bodyid[j]]) in roots]


def in_subtree(model: mujoco.MjModel, body: int, root: int) -> bool:
    """Whether `body` is `root` or lies under it (a parent's id is below its children's)."""
    while body > root:
        body = int(model.body_parentid[body])
    return body == root
