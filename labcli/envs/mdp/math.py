"""Batched rotation helpers over MuJoCo's quaternions (w, x, y, z), torch only."""

from __future__ import annotations

import functools
import itertools

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
# The products a_i b_j of two quaternions' components, in row-major order.
_PAIRS = list(itertools.product(range(4), repeat=2))


def _sign_table(terms: tuple[dict, ...], products: list[tuple]) -> list[list[float]]:
    """A row per product, a column per component: the product's sign in it (0: not in it)."""
    return [[float(component.get(key, 0)) for component in terms] for key in products]


QUAT_OUTER_TO_ROTATION = _sign_table(_R_TERMS, _PAIRS)

# The Hamilton product a b, (w, x, y, z), as signs of the products a_i b_j.
_MUL_TERMS = (
    {(_W, _W): 1, (_X, _X): -1, (_Y, _Y): -1, (_Z, _Z): -1},
    {(_W, _X): 1, (_X, _W): 1, (_Y, _Z): 1, (_Z, _Y): -1},
    {(_W, _Y): 1, (_X, _Z): -1, (_Y, _W): 1, (_Z, _X): 1},
    {(_W, _Z): 1, (_X, _Y): 1, (_Y, _X): -1, (_Z, _W): 1},
)
# The quaternion of extrinsic x-y-z angles, as signs of the products of their half angles'
# cosines (0) and sines (1), (roll, pitch, yaw): w = cr cp cy + sr sp sy, and so on.
_RPY_TERMS = (
    {(0, 0, 0): 1, (1, 1, 1): 1},
    {(1, 0, 0): 1, (0, 1, 1): -1},
    {(0, 1, 0): 1, (1, 0, 1): 1},
    {(0, 0, 1): 1, (1, 1, 0): -1},
)
_SIGNS = {"mul": _sign_table(_MUL_TERMS, _PAIRS),
          "rpy": _sign_table(_RPY_TERMS, list(itertools.product(range(2), repeat=3)))}


@functools.cache
def _signs(name: str, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """A sign table on the device, made once: not copied from the host in a captured step.
    Not an inference tensor, though first made in a rollout: autograd may read it later."""
    with torch.inference_mode(False):
        return torch.tensor(_SIGNS[name], dtype=dtype, device=device)


def _signed_sum(products: torch.Tensor, name: str) -> torch.Tensor:
    """`[..., k]` products to `[..., 4]` sums by a sign table: a few kernels on a GPU, where
    one expression per component is dozens, and no matrix product (TF32 under `agent.tf32`)."""
    return (products[..., None] * _signs(name, products.device, products.dtype)).sum(dim=-2)


def wrap_to_pi(angle: torch.Tensor) -> torch.Tensor:
    return torch.atan2(torch.sin(angle), torch.cos(angle))


def quat_from_rpy(roll: torch.Tensor, pitch: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """Unit quaternions `[n, 4]` of extrinsic x-y-z angles (inverse of `roll_pitch_yaw`)."""
    half = torch.stack((roll, pitch, yaw), dim=-1) * 0.5
    r, p, y = torch.stack((half.cos(), half.sin()), dim=-1).unbind(-2)  # [n, 2] each
    return _signed_sum((r[:, :, None, None] * p[:, None, :, None] * y[:, None, None, :])
                       .flatten(1), "rpy")


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The Hamilton products `a b`, `[n, 4]`."""
    return _signed_sum((a[:, :, None] * b[:, None, :]).flatten(1), "mul")


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
