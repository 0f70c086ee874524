"""Named views of a robot's state: the actuated joints' positions, velocities and limits, in
actuator order, and, for a floating base (a free joint), the root body's pose and velocities.
A planar base (Hopper's and Walker2d's slide and hinge joints) or a fixed one (an arm) has no
root state: a term that reads it is one line saying so. Made once; `update()` recomputes the
derived quantities in place after every change of the state."""

from __future__ import annotations

import mujoco
import torch

from labcli.envs.mdp import math, names
from labcli.envs.sim import Sim
from labcli.errors import LabError
from labcli.mjtree import robot_free_joints

FREE = mujoco.mjtJoint.mjJNT_FREE
# What only a floating base has (the private names: its rotation's entries, read by roll, pitch
# and yaw).
ROOT_STATE = frozenset({
    "root_qpos", "root_qvel", "root_pos", "root_xy", "root_height", "root_quat",
    "root_lin_vel_w", "root_ang_vel_b", "root_lin_vel_b", "rotation", "projected_gravity_b",
    "forward_w", "forward_xy", "up_z", "_r00", "_r10", "_r20", "_r21"})


def columns(state: torch.Tensor, addresses: list[int]) -> tuple[torch.Tensor, torch.Tensor | None]:
    """`state[:, addresses]` as a live view where the addresses are consecutive (no copy per
    step), else a buffer and the index to gather it with (`gather_columns`)."""
    first = addresses[0] if addresses else 0
    if addresses == list(range(first, first + len(addresses))):
        return state[:, first:first + len(addresses)], None
    index = torch.tensor(addresses, dtype=torch.long, device=state.device)
    return state.new_empty(state.shape[0], len(addresses)), index


class Robot:
    """The robot of a task: `joint_*` views of the joints its actuators drive and, with a
    floating base, `root_*` views of its free joint's state. Positions in the world frame,
    `*_b` in the root body's frame."""

    def __init__(self, sim: Sim, root_body: str | None = None, default_pose: str | None = None):
        model = self.model = sim.model
        self.sim = sim
        self.root_joint = self._root_joint(model, root_body)
        self.floating = self.root_joint is not None
        self._joints(sim, default_pose)
        if self.floating:
            self._root(sim, self.root_joint)
        self._per_state: dict[object, torch.Tensor] = {}
        self.update()

    def __getattr__(self, name: str):
        # Only for what the instance lacks: a floating base's state, read on another base.
        if name in ROOT_STATE:
            shown = name if name.startswith("root_") else "orientation"
            raise LabError(f"a term reads the robot's {shown}, which needs a floating base (a "
                           f"free joint), and model '{names.model_name(self.model)}' has none "
                           "(its base is planar or fixed)",
                           "use terms of its joints and actuators, or write the term for its "
                           "base from task.sim's qpos and qvel (docs/plugins.md, 'Planar and "
                           "fixed bases')")
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def _root(self, sim: Sim, joint: int) -> None:
        model = sim.model
        self.root_body = int(model.jnt_bodyid[joint])
        qa, da = int(model.jnt_qposadr[joint]), int(model.jnt_dofadr[joint])
        self.root_qpos, self.root_qvel = slice(qa, qa + 7), slice(da, da + 6)
        self.root_pos = sim.qpos[:, qa:qa + 3]
        self.root_xy, self.root_height = self.root_pos[:, :2], self.root_pos[:, 2]
        self.root_quat = sim.qpos[:, qa + 3:qa + 7]
        # MuJoCo's free joint: linear velocity in the world frame, angular in the body's.
        self.root_lin_vel_w = sim.qvel[:, da:da + 3]
        self.root_ang_vel_b = sim.qvel[:, da + 3:da + 6]
        n, dev, dtype = sim.num_envs, sim.qpos.device, sim.qpos.dtype
        # Derived once per state (update()), from the root's rotation matrix R (world from
        # body): its columns and rows are the axes and gravity, its entries the angles.
        r = self.rotation = torch.empty(n, 3, 3, dtype=dtype, device=dev)
        self._qq = torch.empty(n, 4, 4, dtype=dtype, device=dev)
        # Products summed, not matrix products: those may run in TF32 on a GPU (`agent.tf32`),
        # and the env's values stay float32's whatever the learner's precision.
        self._qq_to_r = torch.as_tensor(math.QUAT_OUTER_TO_ROTATION, dtype=dtype, device=dev)
        self._qq_terms = torch.empty(n, 16, 9, dtype=dtype, device=dev)
        self._v_terms = torch.empty(n, 3, 3, dtype=dtype, device=dev)
        self.root_lin_vel_b = torch.empty(n, 3, dtype=dtype, device=dev)
        self.projected_gravity_b = torch.empty(n, 3, dtype=dtype, device=dev)
        self.forward_w = r[:, :, 0]  # the root's x axis in the world: a view of R
        self.forward_xy = r[:, :2, 0]
        # The root's z axis projected on the world's up (R22, -projected_gravity_b[:, 2]): the
        # cosine of its tilt.
        self.up_z = r[:, 2, 2]
        self._r00, self._r10, self._r20, self._r21 = r[:, 0, 0], r[:, 1, 0], r[:, 2, 0], r[:, 2, 1]
        # The views `update` reads and writes, taken once: each costs as much as an op on it.
        q = self.root_quat
        self._q_col, self._q_row = q[:, :, None], q[:, None, :]
        self._qq_col, self._r_flat = self._qq.view(n, 16, 1), r.view(n, 9)
        self._v_col = self.root_lin_vel_w[:, :, None]
        self._r_row2 = r[:, 2, :]

    def _joints(self, sim: Sim, default_pose: str | None) -> None:
        model = sim.model
        self.actuators = list(range(model.nu))
        joint_ids = []
        for a in self.actuators:
            if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
                raise LabError(f"actuator '{names.all_names(model, 'actuator')[a]}' of model "
                               f"'{names.model_name(model)}' drives no joint",
                               "robot tasks drive hinge or slide joints through actuators")
            joint_ids.append(int(model.actuator_trnid[a, 0]))
        self.joint_ids = joint_ids
        self.joint_names = [names.all_names(model, "joint")[j] for j in joint_ids]
        qadr = [int(model.jnt_qposadr[j]) for j in joint_ids]
        dadr = [int(model.jnt_dofadr[j]) for j in joint_ids]
        self.joint_pos, self._qidx = columns(sim.qpos, qadr)
        self.joint_vel, self._didx = columns(sim.qvel, dadr)
        self._writes = [(sim.qpos, *_writer(sim.qpos, qadr)), (sim.qvel, *_writer(sim.qvel, dadr))]
        dev, dtype = sim.qpos.device, sim.qpos.dtype

        def row(values) -> torch.Tensor:
            return torch.as_tensor(values, dtype=dtype, device=dev).expand(
                sim.num_envs, len(joint_ids)).contiguous()

        limited = model.jnt_limited[joint_ids].astype(bool)
        lower = torch.as_tensor(model.jnt_range[joint_ids, 0])
        upper = torch.as_tensor(model.jnt_range[joint_ids, 1])
        # An unlimited joint's "limits" are wide enough that normalizing leaves it near 0.
        lower[~torch.as_tensor(limited)], upper[~torch.as_tensor(limited)] = -1e3, 1e3
        self.joint_lower, self.joint_upper = row(lower), row(upper)
        self._joint_range = self.joint_upper - self.joint_lower
        # The default pose: a keyframe (Isaac Lab's init_state), else the MJCF's qpos0. Not by
        # overwriting qpos0, which is also the reference of hinge angles in MuJoCo's kinematics.
        home = (model.key_qpos[names.resolve_one(model, "key", default_pose)]
                if default_pose is not None else model.qpos0)
        # The whole default state's qpos `[n, nq]` (an object's pose too).
        self.default_qpos = torch.as_tensor(home, dtype=dtype, device=dev).expand(
            sim.num_envs, model.nq).contiguous()
        self._home_is_qpos0 = default_pose is None
        self.default_joint_pos = row(home[qadr])
        # What each joint's encoder adds to its position (an `EncoderBias` event draws it; it
        # then sets `biased`, and position targets are taken back by it).
        self.encoder_bias = torch.zeros_like(self.default_joint_pos)
        self.biased = False
        gear = torch.as_tensor(model.actuator_gear[self.actuators, 0]).abs()
        self.gear = row(gear)
        self.gear_ratio_scaled = row(gear / gear.max())

    # The root's roll, pitch and yaw (rad; extrinsic x-y-z, as `math.quat_from_rpy`), from R
    # once per state when a term reads them: most tasks read one or none.
    @property
    def roll(self) -> torch.Tensor:
        return self.per_state("roll", lambda: torch.atan2(self._r21, self.up_z))

    @property
    def pitch(self) -> torch.Tensor:
        return self.per_state("pitch", lambda: torch.asin(self._r20.clamp(-1.0, 1.0)).neg_())

    @property
    def yaw(self) -> torch.Tensor:
        return self.per_state("yaw", lambda: torch.atan2(self._r10, self._r00))

    @staticmethod
    def _root_joint(model: mujoco.MjModel, root_body: str | None) -> int | None:
        """The free joint of `root_body`, else the robot's first free joint; None: a planar or
        fixed base."""
        if root_body is not None:
            body = names.resolve_one(model, "body", root_body)
            joint = int(model.body_jntadr[body])
            if joint < 0 or model.jnt_type[joint] != FREE:
                raise LabError(f"body '{root_body}' of model '{names.model_name(model)}' has no "
                               "free joint", "name the floating base as root_body")
            return joint
        free = robot_free_joints(model)
        return free[0] if free else None

    def update(self) -> None:
        if self._qidx is not None:
            torch.index_select(self.sim.qpos, 1, self._qidx, out=self.joint_pos)
        if self._didx is not None:
            torch.index_select(self.sim.qvel, 1, self._didx, out=self.joint_vel)
        if self.floating:
            self._update_root()
        self.forget_derived()

    def _update_root(self) -> None:
        torch.mul(self._q_col, self._q_row, out=self._qq)
        torch.mul(self._qq_col, self._qq_to_r, out=self._qq_terms)
        torch.sum(self._qq_terms, dim=1, out=self._r_flat)
        # R^T v: (R^T v)_j = sum_i v_i R_ij.
        torch.mul(self._v_col, self.rotation, out=self._v_terms)
        torch.sum(self._v_terms, dim=1, out=self.root_lin_vel_b)
        torch.neg(self._r_row2, out=self.projected_gravity_b)  # R^T (0, 0, -1)

    def forget_derived(self) -> None:
        """Drop the values `per_state` cached: the next use computes them again."""
        self._per_state.clear()

    def joint_pos_normalized(self) -> torch.Tensor:
        """Joint positions mapped from their limits to [-1, 1] (once per state)."""
        return self.per_state("joint_pos_normalized", lambda: (
            (2.0 * self.joint_pos - self.joint_upper - self.joint_lower) / self._joint_range))

    def per_state(self, key: object, compute):
        """`compute()`, once per state: terms that share a derived value (the direction to a
        target) compute it once until the state changes."""
        value = self._per_state.get(key)
        if value is None:
            value = self._per_state[key] = compute()
        return value

    def reset_to_default_pose(self, mask: torch.Tensor) -> None:
        """The sim resets envs to qpos0; this puts the envs in `mask` at the default pose."""
        if not self._home_is_qpos0:
            torch.where(mask[:, None], self.default_qpos, self.sim.qpos, out=self.sim.qpos)

    def write_joints(self, pos: torch.Tensor, vel: torch.Tensor, mask: torch.Tensor) -> None:
        """Set the actuated joints of the envs in `mask` to `pos`, `vel` `[n, joints]`."""
        m = mask[:, None]
        for (state, view, index), value in zip(self._writes, (pos, vel), strict=True):
            if index is None:
                torch.where(m, value, view, out=view)
            else:
                state.index_copy_(1, index, torch.where(m, value, state.index_select(1, index)))


def _writer(state: torch.Tensor, addresses: list[int]) -> tuple[torch.Tensor, torch.Tensor | None]:
    view, index = columns(state, addresses)
    return (view, None) if index is None else (state, index)
