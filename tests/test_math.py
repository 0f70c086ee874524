"""labcli.envs.mdp.math against MuJoCo's own quaternion functions."""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from labcli.envs.mdp import math


def _unit_quats(n: int, seed: int) -> torch.Tensor:
    q = torch.randn(n, 4, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    return q / q.norm(dim=1, keepdim=True)


def test_quat_mul_is_mujoco_s_product_and_broadcasts_one_quaternion():
    a, b = _unit_quats(32, 0), _unit_quats(32, 1)
    want = np.empty((32, 4))
    for i in range(32):
        mujoco.mju_mulQuat(want[i], a[i].numpy(), b[i].numpy())
    torch.testing.assert_close(math.quat_mul(a, b), torch.from_numpy(want), rtol=0, atol=1e-15)
    torch.testing.assert_close(math.quat_mul(a[:1], b), math.quat_mul(a[:1].expand(32, 4), b))
    i, j, k = torch.eye(4, dtype=torch.float64)[1:, None]  # (0, 1, 0, 0) and so on
    torch.testing.assert_close(math.quat_mul(i, j), k)
    torch.testing.assert_close(math.quat_mul(j, i), -k)


def test_quat_from_rpy_is_mujoco_s_extrinsic_xyz_the_product_of_three_turns():
    angles = torch.rand(32, 3, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    angles = (angles - 0.5) * torch.tensor([3.0, 1.5, 6.0], dtype=torch.float64)
    got = math.quat_from_rpy(*angles.unbind(1))
    want = np.empty((32, 4))
    for n in range(32):
        mujoco.mju_euler2Quat(want[n], angles[n].numpy(), "XYZ")
    torch.testing.assert_close(got, torch.from_numpy(want), rtol=0, atol=1e-15)
    zero = torch.zeros(32, dtype=torch.float64)
    roll, pitch, yaw = (math.quat_from_rpy(*(angles[:, k] if k == axis else zero
                                               for k in range(3))) for axis in range(3))
    torch.testing.assert_close(got, math.quat_mul(yaw, math.quat_mul(pitch, roll)))
    single = math.quat_from_rpy(*angles[:1].float().unbind(1))
    assert single.dtype == torch.float32 and single.shape == (1, 4)


def test_products_first_made_in_inference_mode_still_serve_autograd():
    math._signs.cache_clear()
    a, b = _unit_quats(4, 3), _unit_quats(4, 4)
    with torch.inference_mode():
        math.quat_mul(a, b)
    a.requires_grad_(True)
    math.quat_mul(a, b).sum().backward()
    assert a.grad is not None and a.grad.shape == (4, 4)
