"""bench/replay_diff.py's comparison of a recording in lab with its replay in mjlab, on arrays
made here: each env's steps count up to the first episode's end on either side."""

from __future__ import annotations

import benchscripts
import numpy as np
import pytest

STEPS, ENVS, JOINTS = 4, 2, 8


def test_the_joints_are_compared_until_either_side_s_episode_ends():
    replay_diff = benchscripts.load("replay_diff")
    cube_rest = np.zeros((ENVS, 7))
    cube_rest[:, 2] = 0.01  # the cubes' rest height
    joints = np.zeros((STEPS, ENVS, JOINTS))
    theirs = joints.copy()
    theirs[:, 0, 1] = [0.01, 0.02, 0.03, 0.04]  # env 0: the shoulder drifts apart
    theirs[:, 1, 7] = [0.005, 0.5, 0.5, 0.5]  # env 1: ends after its first step, then differs
    ended = np.zeros((STEPS, ENVS), dtype=bool)
    mjlab_ended = ended.copy()
    mjlab_ended[1, 1] = True
    cubes = np.zeros((STEPS, ENVS, 3))
    cubes[-1, :, 2] = [0.1, 0.05]
    lab = {"settled_joints": np.zeros((ENVS, JOINTS)), "cube_rest": cube_rest,
           "joints": joints, "cubes": cubes, "ended": ended}
    mjlab = {"settled_joints": np.full((ENVS, JOINTS), 0.002), "joints": theirs,
             "cubes": cubes - 0.01, "ended": mjlab_ended}
    row = replay_diff.compare(lab, mjlab)
    assert row["settled_joints_apart"] == pytest.approx(0.002)
    # Per step the larger of the envs' differences: 0.01 (env 1's 0.005 is smaller), then env
    # 0's alone, as env 1's episode ended at step 1.
    assert row["steps_compared"] == STEPS
    assert row["joints_apart_median"] == pytest.approx(0.025)
    assert row["joints_apart_max"] == pytest.approx(0.04)
    assert row["ended_envs"] == 1
    assert row["lab_cube_raised"] == pytest.approx([0.09, 0.04])
    assert row["mjlab_cube_raised"] == pytest.approx([0.08, 0.03])
