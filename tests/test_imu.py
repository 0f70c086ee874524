"""Projected gravity from an IMU site and its randomized mounting (`ProjectedGravity.site`,
`mounting_range`), against hand-computed rotations of a Go1 standing upright after its reset."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
import torch
from conftest import needs_menagerie
from rich.console import Console

from labcli.errors import LabError
from labcli.gym import make_env

pytestmark = needs_menagerie("unitree_go1")  # go1-flat's robot
GRAVITY = "env.observations.projected_gravity"


def _gravity(*settings: str, num_envs: int = 4, steps: int = 0) -> list[torch.Tensor]:
    """The projected-gravity columns after the reset and after each of `steps` steps."""
    env = make_env("go1-flat", num_envs, backend="cpu", overrides=[
        "env.observation_noise=false", *settings])
    i = env.observation_names.index("projected_gravity.x")
    obs, _ = env.reset(seed=0)
    seen = [obs[:, i:i + 3]]
    actions = torch.rand(steps, num_envs, 12, generator=torch.Generator().manual_seed(1)) - 0.5
    for action in actions:
        obs, *_ = env.step(action)
        seen.append(obs[:, i:i + 3])
    env.close()
    return seen


def test_an_imu_mounted_turned_sees_gravity_turned():
    """Upright, gravity is (0, 0, -1) in the root's frame; an IMU rolled by a sees
    R_x(a)^T (0, 0, -1) = (0, -sin a, -cos a), pitched by b: (sin b, 0, -cos b)."""
    (upright,) = _gravity()
    torch.testing.assert_close(upright, torch.tensor([[0.0, 0.0, -1.0]] * 4))
    (rolled,) = _gravity(f"{GRAVITY}.site=imu", f"{GRAVITY}.mounting_range={{roll: [0.1, 0.1]}}")
    torch.testing.assert_close(rolled, torch.tensor([[0.0, -math.sin(0.1), -math.cos(0.1)]] * 4))
    (pitched,) = _gravity(f"{GRAVITY}.mounting_range={{pitch: [-0.2, -0.2]}}")
    torch.testing.assert_close(pitched,
                               torch.tensor([[math.sin(-0.2), 0.0, -math.cos(-0.2)]] * 4))


def test_the_imu_site_of_the_root_reads_the_roots_gravity_as_it_moves():
    """Menagerie's Go1 `imu` site sits at the trunk's origin, unturned."""
    root = _gravity(steps=3)
    imu = _gravity(f"{GRAVITY}.site=imu", steps=3)
    for a, b in zip(root, imu, strict=True):
        torch.testing.assert_close(a, b)
    assert not torch.equal(root[-1], root[0])  # the trunk did turn


def test_each_env_draws_its_mounting_at_each_episode():
    ranges = f"{GRAVITY}.mounting_range={{roll: [-0.1, 0.1], yaw: [-0.5, 0.5]}}"
    first, *_, after = _gravity(ranges, "env.episode_length_s=0.1", num_envs=64, steps=5)
    # Upright, a yaw leaves gravity alone: (0, -sin(roll), -cos(roll)), each env's own roll...
    torch.testing.assert_close(first[:, 0], torch.zeros(64))
    roll = torch.asin(-first[:, 1])
    assert roll.abs().max() <= 0.1 + 1e-6 and roll.std() > 0.02
    # ...and the episodes all ended at the 5th step: new draws.
    assert not torch.allclose(after, first, atol=1e-3)


def test_a_site_off_the_root_or_a_wrong_key_is_one_line():
    with pytest.raises(LabError, match="no site named 'imuu'"):
        _gravity(f"{GRAVITY}.site=imuu")
    with pytest.raises(LabError, match="is not on the root body 'trunk'"):
        _gravity(f"{GRAVITY}.site=FR")
    with pytest.raises(LabError, match="mounting_range has x: its keys are roll, pitch, yaw"):
        _gravity(f"{GRAVITY}.mounting_range={{x: [0, 1]}}")


def test_the_plain_loop_reads_gravity_in_the_imu_frame(tmp_path):
    """The export names the site; labcli/sim2sim.py turns gravity into it as lab does."""
    from labcli.runs import closed_loop, export, training
    from labcli.sim2sim import PlainLoop

    outcome = training.train(
        "go1-flat", "rsl_rl", num_envs=4, max_iterations=1, logs_dir=tmp_path,
        console=Console(file=io.StringIO()), command=["lab", "test"],
        overrides=["agent.num_steps_per_env=2", f"{GRAVITY}.site=imu",
                   "env.episode_length_s=1"])
    result = export.export("onnx", run_dir=outcome.run.dir)
    loop = PlainLoop(result.path)
    (term,) = [t for t in loop.meta["deployment"]["observations"]
               if t["kind"] == "projected_gravity"]
    assert term["settings"]["site"] == "imu"
    index = loop.meta["deployment"]["observations"].index(term)
    qpos = loop.model.qpos0.copy()
    qpos[3:7] = [math.cos(0.15), math.sin(0.15), 0.0, 0.0]  # rolled by 0.3 rad
    loop.reset(qpos, np.zeros(loop.model.nv))
    np.testing.assert_allclose(loop.terms[index](np.zeros(3)),
                               [0.0, -math.sin(0.3), -math.cos(0.3)], atol=1e-12)
    assert closed_loop.check(run_dir=outcome.run.dir, episodes=2).passed
