"""bench/hfield_contacts.py: a foot-sized sphere put into a task's height fields, its contacts
in MuJoCo and in MuJoCo Warp."""

from __future__ import annotations

import numpy as np
import pytest
from benchscripts import load

from labcli.envs.mdp import terrain_model

contacts = load("hfield_contacts")
SMALL = ["env.terrain.rows=2", "env.terrain.cols=6"]


def test_places_lie_on_their_type_s_patches_off_the_platforms():
    model, cfg, patches = contacts.terrain_with_sphere("go1-rough", SMALL, 0.023)
    points = contacts.places(cfg, patches, 64, np.random.default_rng(0))
    assert set(points) == {"boxes", "rough", "slope", "slope_down"}  # not the stairs' boxes
    for name, xy in points.items():
        row = np.floor(xy[:, 0] / cfg.size + cfg.rows / 2).astype(int)
        col = np.floor(xy[:, 1] / cfg.size + len(patches.columns) / 2).astype(int)
        assert {patches.columns[c] for c in col} == {name}
        offset = np.abs(xy - patches.origins[row, col, :2]).max(axis=1)
        assert offset.min() >= cfg.used[name].platform / 2
        assert offset.max() <= cfg.size / 2 - terrain_model.FLAT_EDGE


def test_the_sphere_is_put_as_deep_as_asked_in_mujoco():
    import mujoco

    model, cfg, patches = contacts.terrain_with_sphere("go1-rough", SMALL, 0.023)
    data = mujoco.MjData(model)
    for xy in contacts.places(cfg, patches, 8, np.random.default_rng(1))["slope"]:
        z = contacts.height_at_depth(model, data, xy, 0.005)
        assert contacts.deepest_c(model, data, xy, z)[0] == pytest.approx(-0.005, abs=1e-6)


def test_a_task_without_terrain_is_refused():
    with pytest.raises(SystemExit, match="no terrain"):
        contacts.terrain_with_sphere("go1-flat", [], 0.023)


def test_on_a_flat_height_field_the_engines_agree():
    pytest.importorskip("mujoco_warp")
    others = ("stairs", "stairs_down", "boxes", "rough", "slope", "slope_down")
    flat = [f"env.terrain.types.{name}=null" for name in others]
    flat.append("env.terrain.types.flat={type: wave, amplitude: [0.0, 0.0]}")
    model, cfg, patches = contacts.terrain_with_sphere("go1-rough", SMALL + flat, 0.023)
    points = contacts.places(cfg, patches, 16, np.random.default_rng(0))
    (row,) = contacts.compare(model, points, 0.005)
    assert row == {"type": "flat", "places": 16, "apart": 0, "median": 0.0, "largest": 0.0,
                   "turned": 0}


def test_on_slopes_of_meshes_the_engines_agree():
    pytest.importorskip("mujoco_warp")
    meshes = [f"env.terrain.types.{name}.meshes=true" for name in ("slope", "slope_down")]
    others = [f"env.terrain.types.{name}=null" for name in ("boxes", "rough")]
    model, cfg, patches = contacts.terrain_with_sphere("go1-rough", SMALL + meshes + others, 0.01)
    points = contacts.places(cfg, patches, 32, np.random.default_rng(0))
    rows = contacts.compare(model, points, 0.005)
    assert [(row["type"], row["apart"]) for row in rows] == [("slope", 0), ("slope_down", 0)]
