"""Batched rotation helpers over MuJoCo's quaternions (w, x, y, z), torch only."""

from __future__ import annotations

import torch

# R (3x3, row-major) of a unit quaternion q = (w, x, y, z) as a linear map of its outer product
# q q^T (4x4, row-major): `(q q^T).view(n, 16) @ QUAT_OUTER_TO_ROTATION` is R.view(n, 9).
_W, _X, _Y, _Z = range(4)
_R_TERMS = (
    {(_W, _W): 1, (_X, _X): 1, (_Y, _Y): -1, (_Z, _Z): -1},  # R00 = ww + xx - yy - zz
    {(_X, _Y): 1, (_Y, _X): 1, (_W, _Z): -1, (_Z, _W): -1},  # R01 = 2 (xy - wz)
    {(_X, _Z): 1, (_Z, _X): 1, (_W, _Y): 1, (_Y, _W): 1},    # R02 = 2 (xz + wy)
    {(_X, _Y): 1, (_Y, _X): 1, (_W, _Z): 1, (_Z, _W): 1},    # R10 = 2 (xy + wz)
    {(_W, _W): 1, (_X, _X): -1, (_Y, _Y): 1, (_Z, _Z): -1},  # R11
    {(_Y, _Z): 1, (_Z, _Y): 1, (_W, _X): -1, (_X, _W): -1},  # R12 = 2 (yz - wx)
    {(_X, _Z): 1, (_Z, _X): 1, (_W, _Y): -1, (_Y, _W): -1},  # R20 = 2 (xz - wy)
    {(_Y, _Z): 1, (_Z, _Y): 1, (_W, _X): 1, (_X, _W): 1},    # R21 = 2 (yz + wx)
    {(_W, _W): 1, (_X, _X): -1, (_Y, _Y): -1, (_Z, _Z): 1},  # R22
)
QUAT_OUTER_TO_ROTATION = [[float(terms.get((i // 4, i % 4), 0)) for terms in _R_TERMS]
                          for i in range(16)]


def wrap_to_pi(angle: torch.Tensor) -> torch.Tensor:
    return torch.atan2(torch.sin(angle), torch.cos(angle))


def quat_from_rpy(roll: torch.Tensor, pitch: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """Unit quaternions `[n, 4]` of extrinsic x-y-z angles (inverse of `roll_pitch_yaw`)."""
    cr, sr = torch.cos(roll * 0.5), torch.sin(roll * 0.5)
    cp, sp = torch.cos(pitch * 0.5), torch.sin(pitch * 0.5)
    cy, sy = torch.cos(yaw * 0.5), torch.sin(yaw * 0.5)
    return torch.stack((cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                        cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy), dim=1)


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The Hamilton products `a b`, `[n, 4]`."""
    aw, ax, ay, az = a.unbind(1)
    bw, bx, by, bz = b.unbind(1)
    return torch.stack((aw * bw - ax * bx - ay * by - az * bz,
                        aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw), dim=1)


def quat_apply_inverse(quat: torch.Tensor, vec: torch.Tensor) -> torch.Tensor:
    """Vectors `[n, 3]` turned by the inverse of unit quaternions `[n, 4]`: a world (or parent)
    frame's vector in the quaternion's frame."""
    xyz = quat[:, 1:]
    t = torch.linalg.cross(xyz, vec).mul_(2.0)
    return vec - quat[:, :1] * t + torch.linalg.cross(xyz, t)


def quat_apply(quat: torch.Tensor, vec: torch.Tensor) -> torch.Tensor:
    """Vectors `[n, 3]` turned by unit quaternions `[n, 4]`: the quaternion's frame's vector in
    the world (or parent) frame."""
    xyz = quat[:, 1:]
    t = torch.linalg.cross(xyz, vec).mul_(2.0)
    return vec + quat[:, :1] * t + torch.linalg.cross(xyz, t)


def yaw_of(quat: torch.Tensor) -> torch.Tensor:
    """The heading (rad) of unit quaternions `[n, 4]`: atan2(R10, R00), as `Robot.yaw`."""
    w, x, y, z = quat.unbind(1)
    return torch.atan2(2.0 * (x * y + w * z), w * w + x * x - y * y - z * z)
