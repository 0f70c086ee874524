"""The terrain generator (labcli/envs/mdp/terrain.py, terrain_model.py) on real MuJoCo: the
config's checks, the columns' shares, the same geometry from the same seed, each patch's start
point and the stairs' and slopes' heights against MuJoCo's own ray casting, the height map
against the rays, and a Go1 dropped on the hardest patch of each type standing on it."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from conftest import needs_menagerie, needs_warp
from pydantic import ValidationError

from labcli.envs import metrics
from labcli.envs.mdp import terrain as t
from labcli.envs.mdp import terrain_model as tm

GO1 = Path(__file__).parents[1] / "tasks" / "lab_locomotion" / "go1.xml"


def _small(**changes) -> t.TerrainConfig:
    """Every type once, 3 rows of 4 m patches: small enough to build in a blink."""
    cfg = t.TerrainConfig(size=4.0, rows=3, cols=8, border=1.0, types={
        "flat": t.Flat(platform=1.0),
        "stairs": t.PyramidStairs(platform=1.0, step_height=(0.05, 0.15)),
        "stairs_down": t.PyramidStairs(platform=1.0, step_height=(0.05, 0.15), inverted=True),
        "slope": t.PyramidSlope(platform=1.0, slope=(0.1, 0.3)),
        "rough": t.RandomRough(platform=1.0),
        "waves": t.Wave(platform=1.0, waves=2),
        "obstacles": t.DiscreteObstacles(platform=1.0, count=5, width=(0.3, 0.8)),
        "stones": t.SteppingStones(platform=1.0),
    })
    return cfg.model_copy(update=changes)


def _build(cfg: t.TerrainConfig) -> tuple[mujoco.MjModel, tm.Terrain]:
    spec = mujoco.MjSpec.from_file(str(GO1))
    terrain = tm.apply(spec, cfg)
    return spec.compile(), terrain


def _ray_heights(model: mujoco.MjModel, points: np.ndarray) -> np.ndarray:
    """The terrain's surface under each (x, y), by MuJoCo's ray casting from 10 m up."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    terrain = set(tm.geom_ids(model))
    geom = np.zeros(1, np.int32)
    out = []
    for x, y in points:
        # Static geoms only (flg_static), the robot's excluded by body: its trunk is at x = y = 0.
        dist = mujoco.mj_ray(model, data, np.array([x, y, 10.0]), np.array([0.0, 0.0, -1.0]),
                             None, 1, model.body("trunk").id, geom)
        assert dist >= 0 and geom[0] in terrain, (x, y)
        out.append(10.0 - dist)
    return np.array(out)


def test_the_config_says_what_does_not_fit():
    with pytest.raises(ValidationError, match="whole number"):
        _small(size=4.05).model_validate(_small(size=4.05).model_dump())
    with pytest.raises(ValidationError, match="at least as many columns"):
        t.TerrainConfig.model_validate({**_small().model_dump(), "cols": 3})
    with pytest.raises(ValidationError, match="platform 5.0 m does not fit"):
        t.TerrainConfig.model_validate({**_small().model_dump(),
                                        "types": {"flat": {"type": "flat", "platform": 5.0}}})
    with pytest.raises(ValidationError, match="type"):  # an unknown type names the known ones
        t.TerrainConfig.model_validate({**_small().model_dump(),
                                        "types": {"ice": {"type": "ice"}}})


def test_the_columns_are_shared_by_proportion():
    columns = t.rough().columns()
    assert len(columns) == 20
    counts = {name: columns.count(name) for name in t.rough().types}
    assert counts == {"flat": 4, "stairs": 4, "stairs_down": 4, "slope": 2, "slope_down": 2,
                      "rough": 2, "waves": 2}
    assert columns == sorted(columns, key=list(t.rough().types).index)  # each type together
    # Every type keeps a column, however small its share.
    tiny = t.TerrainConfig(cols=3, types={"a": t.Flat(proportion=100), "b": t.Flat(
        proportion=0.01), "c": t.Wave(proportion=0.01)})
    assert tiny.columns() == ["a", "b", "c"]


def test_the_same_seed_builds_the_same_terrain_and_another_seed_another():
    a, _ = _build(_small())
    b, _ = _build(_small())
    c, _ = _build(_small(seed=1))
    assert np.array_equal(a.hfield_data, b.hfield_data)
    assert np.array_equal(a.geom_pos, b.geom_pos) and np.array_equal(a.geom_size, b.geom_size)
    assert not np.array_equal(a.hfield_data, c.hfield_data)  # rough, obstacles: drawn


def test_the_ground_plane_gives_way_to_the_terrain_with_its_contact_settings():
    model, _ = _build(_small())
    planes = [g for g in range(model.ngeom) if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE]
    assert planes == []
    floor = mujoco.MjModel.from_xml_path(str(GO1)).geom("floor")
    terrain = tm.geom_ids(model)
    assert all(model.geom_bodyid[g] == 0 for g in terrain)  # the world's: posed once
    assert len(terrain) > 8
    for g in terrain:
        assert model.geom_contype[g] == floor.contype and model.geom_conaffinity[g] == \
            floor.conaffinity
        assert np.array_equal(model.geom_friction[g], floor.friction)


def test_every_start_point_is_on_the_surface_mujoco_sees():
    cfg = _small()
    model, terrain = _build(cfg)
    assert terrain.origins.shape == (3, 8, 3)
    assert terrain.columns == list(cfg.types)
    assert np.allclose(terrain.difficulty[:, 0], [0.0, 0.5, 1.0])
    # Rows along x, columns along y, the grid centred on the origin.
    assert np.allclose(terrain.origins[:, 0, 0], [-4.0, 0.0, 4.0])
    assert np.allclose(terrain.origins[0, :, 1], np.arange(8) * 4.0 - 14.0)
    rays = _ray_heights(model, terrain.origins[..., :2].reshape(-1, 2))
    assert np.allclose(rays, terrain.origins[..., 2].ravel(), atol=1e-9)


def test_stairs_rise_and_fall_by_a_step_each_tread():
    cfg = _small()
    model, terrain = _build(cfg)
    row = 2  # difficulty 1: steps of 0.15 m
    for col, sign in ((1, 1), (2, -1)):  # stairs up, stairs down
        x0, y0, top = terrain.origins[row, col]
        # From the flat edge to the platform: treads 0.3 m wide, sampled mid-tread.
        edge = 2.0 - tm.FLAT_EDGE
        steps = int((edge - 0.5) / 0.3)
        points = [(x0 + edge - (i + 0.5) * 0.3, y0) for i in range(steps)]
        assert np.allclose(_ray_heights(model, np.array(points)),
                           sign * 0.15 * np.arange(1, steps + 1), atol=1e-9)
        assert top == pytest.approx(sign * 0.15 * steps)
        assert _ray_heights(model, np.array([(x0 + 1.95, y0)]))[0] == pytest.approx(0.0)


def test_a_slope_rises_as_its_config_says():
    cfg = _small()
    model, terrain = _build(cfg)
    x0, y0, top = terrain.origins[2, 3]  # slope 0.3 at difficulty 1
    run = 2.0 - tm.FLAT_EDGE - 0.5
    assert top == pytest.approx(0.3 * run, abs=cfg.vertical_scale)
    # Half-way down the slope, on a height-field point: half the rise.
    heights = _ray_heights(model, np.array([(x0 + 0.5 + run / 2, y0)]))
    assert heights[0] == pytest.approx(top / 2, abs=cfg.vertical_scale)


def test_the_height_map_is_what_the_rays_see():
    cfg = _small()
    model, _ = _build(cfg)
    heights, (x0, x1, y0, y1) = tm.height_map(model, cfg.horizontal_scale)
    assert (x0, x1, y0, y1) == (-7.0, 7.0, -17.0, 17.0)  # the grid and its 1 m border
    assert not np.isnan(heights).any()
    rng = np.random.default_rng(0)
    # Sample points on the height fields' own grid (between them MuJoCo interpolates).
    iy, ix = rng.integers(0, heights.shape[0], 200), rng.integers(0, heights.shape[1], 200)
    xs = x0 + (ix + 0.5) * cfg.horizontal_scale
    ys = y0 + (iy + 0.5) * cfg.horizontal_scale
    rays = _ray_heights(model, np.stack([xs, ys], axis=1))
    close = np.abs(rays - heights[iy, ix]) < 0.02
    assert close.mean() > 0.9, np.abs(rays - heights[iy, ix]).max()


@pytest.mark.parametrize("inverted", [False, True], ids=["up", "down"])
def test_a_slope_of_meshes_is_the_height_field_s_surface_as_the_rays_see_it(inverted):
    """Up to the height field's quantization and the map's sampling: the same surface, the
    same start points; and the map is what MuJoCo's rays see of the meshes."""
    slope = t.PyramidSlope(platform=1.0, slope=(0.1, 1.0), inverted=inverted)
    field = _small(types={"slope": slope}, cols=1)
    meshes = _small(types={"slope": slope.model_copy(update={"meshes": True})}, cols=1)
    (field_model, field_terrain), (mesh_model, mesh_terrain) = _build(field), _build(meshes)
    assert mujoco.mjtGeom.mjGEOM_MESH in mesh_model.geom_type
    assert mujoco.mjtGeom.mjGEOM_HFIELD not in mesh_model.geom_type[tm.geom_ids(mesh_model)]
    resolution = 0.05
    field_map, extent = tm.height_map(field_model, resolution)
    mesh_map, mesh_extent = tm.height_map(mesh_model, resolution)
    np.testing.assert_array_equal(mesh_extent, extent)
    assert not np.isnan(mesh_map).any()
    # A 45° slope sampled half a sample's width off the field's points, quantized.
    assert np.abs(field_map - mesh_map).max() <= resolution / 2 + field.vertical_scale
    np.testing.assert_allclose(mesh_terrain.origins, field_terrain.origins,
                               atol=field.vertical_scale)
    rng = np.random.default_rng(0)
    iy, ix = rng.integers(0, mesh_map.shape[0], 200), rng.integers(0, mesh_map.shape[1], 200)
    points = np.stack([extent[0] + (ix + 0.5) * resolution, extent[2] + (iy + 0.5) * resolution],
                      axis=1)
    np.testing.assert_allclose(_ray_heights(mesh_model, points), mesh_map[iy, ix], atol=1e-5)


def test_a_go1_stands_on_the_hardest_patch_of_each_type():
    cfg = _small()
    model, terrain = _build(cfg)
    data = mujoco.MjData(model)
    home = model.key("home")
    feet = {model.geom(f"{leg}_foot").id for leg in ("FL", "FR", "RL", "RR")}
    ground = set(tm.geom_ids(model))
    for col, name in enumerate(terrain.columns):
        mujoco.mj_resetDataKeyframe(model, data, home.id)
        x, y, z = terrain.origins[-1, col]
        data.qpos[:3] = (x, y, z + home.qpos[2] + 0.02)
        for _ in range(round(1.0 / model.opt.timestep)):  # the standing pose held
            mujoco.mj_step(model, data)
        # On its feet on the terrain, neither through it nor fallen.
        assert data.qpos[2] - z == pytest.approx(home.qpos[2], abs=0.05), name
        touching = {int(g) for c in data.contact[:data.ncon] for g in c.geom
                    if c.geom[0] in ground or c.geom[1] in ground}
        assert touching & feet == feet, name


@needs_menagerie("unitree_go1")
def test_a_preview_is_written(tmp_path):
    cfg = _small()
    model, terrain = _build(cfg)
    out = tmp_path / "terrain.png"
    tm.save_preview(model, cfg, out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000


# The terrain in a task: start points, the height scan, the curriculum -------------------------
TERRAIN = {"size": 4.0, "rows": 3, "cols": 2, "border": 1.0, "max_start_level": 1, "types": {
    "flat": {"type": "flat", "platform": 1.0},
    "stairs": {"type": "pyramid_stairs", "platform": 1.0, "step_height": [0.1, 0.2]}}}


def _go1_on_terrain(n: int = 8, **changes):
    import json

    from labcli.gym import make_env

    env = make_env("go1-flat", num_envs=n, seed=0, overrides=[
        "env.observation_noise=false", "env.terrain=" + json.dumps({**TERRAIN, **changes})])
    env.reset()
    return env


@needs_menagerie("unitree_go1")
def test_robots_start_on_their_patches_of_the_levels_they_may_start_on():
    env = _go1_on_terrain()
    grid, robot = env.task.terrain, env.task.robot
    # Types spread evenly over the envs; new envs on levels 0 to max_start_level.
    assert grid.types.tolist() == [0, 0, 0, 0, 1, 1, 1, 1]
    assert set(grid.levels.tolist()) <= {0, 1}
    origin = grid.origins[grid.levels, grid.types]
    # Stairs of 4 steps, 0.1 m at level 0 to 0.2 m at level 2.
    assert origin[:, 2].tolist() == pytest.approx([
        0.0 if ty == 0 else 0.4 + 0.2 * lv for lv, ty in zip(grid.levels.tolist(),
                                                              grid.types.tolist(), strict=True)])
    # go1-flat's reset moves the root up to 0.5 m in x and y from the start point.
    offset = robot.root_pos[:, :2] - origin[:, :2]
    assert offset.abs().max() <= 0.5
    home = env.task.model.key("home").qpos[2]
    assert torch.allclose(robot.root_pos[:, 2], origin[:, 2] + home)


@needs_menagerie("unitree_go1")
def test_the_height_scan_is_what_mujocos_rays_see():
    from labcli.envs.mdp import config as c
    from labcli.envs.mdp import observations as o

    env = _go1_on_terrain()
    task = env.task
    scan_cfg = c.HeightScan()
    scan = o.height_scan(task, scan_cfg)
    assert len(scan.names) == 187 and scan.names[0] == "-0.80,-0.50"
    values = scan()
    # The same points by hand: the grid turned by each base's yaw, rays from 10 m up in a copy
    # of the model without the robot in the way.
    model = task.model
    data = mujoco.MjData(model)
    data.qpos[2] = -50.0  # the robot far below the terrain
    mujoco.mj_forward(model, data)
    xs = np.linspace(-0.8, 0.8, 17)
    ys = np.linspace(-0.5, 0.5, 11)
    px, py = np.meshgrid(xs, ys)
    agree = []
    for env_id in range(task.num_envs):
        x0, y0, z0 = task.robot.root_pos[env_id].tolist()
        yaw = float(task.robot.yaw[env_id])
        wx = x0 + np.cos(yaw) * px - np.sin(yaw) * py
        wy = y0 + np.sin(yaw) * px + np.cos(yaw) * py
        hits = _ray_heights(model, np.stack([wx.ravel(), wy.ravel()], axis=1))
        expected = z0 - hits - 0.5
        agree.append(np.abs(values[env_id].numpy() - expected) < 1e-6)
    # Nearest on a 5 cm map: only points within a few centimetres of a stair's edge differ.
    assert np.mean(agree) > 0.95, np.mean(agree)


@needs_menagerie("unitree_go1")
def test_the_curriculum_moves_envs_up_and_down_as_legged_gym_does():
    env = _go1_on_terrain()
    task = env.task
    grid = task.terrain
    command = task.command("base_velocity").command
    grid.levels.copy_(torch.tensor([0, 1, 1, 2, 0, 1, 2, 2]))
    # Far (more than half a 4 m patch), little for the command, enough, far from the top level.
    grid.walked.copy_(torch.tensor([2.5, 0.5, 1.9, 2.5, 0.1, 1.2, 0.1, 2.5]))
    command.zero_()
    command[:, 0] = torch.tensor([1.0, 1.0, 0.1, 1.0, 0.0, 0.1, 1.0, 0.1])
    # 20 s episodes: half the commanded distance is 10 m at 1 m/s, 1 m at 0.1 m/s.
    task.rng.manual_seed(0)
    mask = torch.tensor([True] * 7 + [False])
    grid.reset(mask)
    levels = grid.levels.tolist()
    assert levels[:3] == [1, 0, 1]  # up; down; stays (1.9 m > 1 m asked)
    assert levels[3] in (0, 1, 2)  # past the top: a random level
    assert levels[4:7] == [0, 1, 1]  # asked nothing (stays); stays; down
    assert levels[7] == 2  # not reset: unchanged


@needs_menagerie("unitree_go1")
def test_the_terrain_state_travels_with_the_task_state_and_its_levels_are_logged():
    env = _go1_on_terrain()
    state = env.task.state()
    for name in ("levels", "types", "start", "walked", "started"):
        assert f"terrain/{name}" in state
    figures = env.task.episode_metrics()
    grid = env.task.terrain
    level = grid.levels.double()
    assert torch.equal(figures["terrain/level"], level)
    # Per type, the levels of its envs (the first four flat, the last four stairs) only.
    assert torch.equal(figures["terrain/level/stairs"][4:], level[4:])
    assert figures["terrain/level/stairs"][:4].isnan().all()


@needs_menagerie("unitree_go1")
def test_each_terrain_type_s_level_is_the_mean_of_its_own_ended_episodes():
    env = _go1_on_terrain()
    grid = env.task.terrain
    grid.levels.copy_(torch.tensor([0, 1, 0, 1, 2, 2, 1, 1]))
    # One flat episode and two on stairs time out on the next step; the others go on.
    env.episode_length.copy_(torch.tensor([99, 0, 0, 0, 99, 99, 0, 0]))
    env.max_episode_length = 100
    env.step(torch.zeros(env.action_space.shape))
    stats = env.pop_stats()
    assert stats[metrics.EPISODES] == 3
    assert stats[metrics.TASK_METRIC + "terrain/level"] == pytest.approx(4 / 3)
    assert stats[metrics.TASK_METRIC + "terrain/level/flat"] == 0.0
    assert stats[metrics.TASK_METRIC + "terrain/level/stairs"] == 2.0
    # No stairs episode ends on the next step: its level is not logged, the flat one's is.
    env.episode_length.copy_(torch.tensor([0, 99, 0, 0, 0, 0, 0, 0]))
    env.step(torch.zeros(env.action_space.shape))
    stats = env.pop_stats()
    assert stats[metrics.TASK_METRIC + "terrain/level/flat"] == 1.0
    assert metrics.TASK_METRIC + "terrain/level/stairs" not in stats


@needs_menagerie("unitree_go1")
def test_a_height_scan_without_terrain_is_one_line():
    from labcli.envs.mdp import config as c
    from labcli.envs.mdp import observations as o
    from labcli.errors import LabError
    from labcli.gym import make_env

    env = make_env("go1-flat", num_envs=2, seed=0)
    with pytest.raises(LabError, match="the task has none"):
        o.height_scan(env.task, c.HeightScan())


@pytest.mark.gpu
@needs_warp()
@needs_menagerie("unitree_go1")
def test_both_backends_stand_go1s_on_the_terrain_and_scan_it_alike():
    """MuJoCo Warp collides with the height fields and boxes as MuJoCo does: from the same
    state, robots holding their pose stay on their patches on both backends, and the height
    scans of the same states agree."""
    import json

    from backends import lift_and_copy

    from labcli.gym import make_env

    # Upright against the terrain's normal: its reward is in the step the GPU captures.
    sets = ["env.observation_noise=false", "env.events.push_robot=null",
            "env.terrain=" + json.dumps(TERRAIN),
            "env.rewards.flat_orientation_l2.reference=terrain"]
    cpu = make_env("go1-flat", num_envs=8, backend="cpu", device="cpu", seed=0, overrides=sets)
    gpu = make_env("go1-flat", num_envs=8, backend="warp", device="cuda", seed=0, overrides=sets)
    cpu.reset(), gpu.reset()
    lift_and_copy(cpu, gpu, height=0.0)
    for _ in range(50):
        cpu.step(torch.zeros(8, 12))
        gpu.step(torch.zeros(8, 12, device="cuda"))
    grid = cpu.task.terrain
    home = cpu.task.model.key("home").qpos[2]
    origin = grid.origins[grid.levels, grid.types]
    for env in (cpu, gpu):
        height = env.task.robot.root_pos[:, 2].cpu().double()
        assert torch.allclose(height, origin[:, 2] + home, atol=0.05), env.backend
    assert torch.allclose(gpu.task.robot.root_pos.cpu().double(), cpu.task.robot.root_pos,
                          atol=1e-2)
    from labcli.envs.mdp import config as c
    from labcli.envs.mdp import observations as o

    lift_and_copy(cpu, gpu, height=0.0)
    cpu.task.update(), gpu.task.update()
    scans = [o.height_scan(env.task, c.HeightScan())() for env in (cpu, gpu)]
    assert torch.allclose(scans[1].cpu().double(), scans[0], atol=1e-4)
    from labcli.envs.mdp import rewards

    upright = c.FlatOrientationL2(weight=-1.0, reference="terrain")
    tilts = [rewards.flat_orientation_l2(env.task, upright) for env in (cpu, gpu)]
    assert torch.allclose(tilts[1].cpu().double(), tilts[0], atol=1e-5)


@needs_menagerie("unitree_g1")
def test_heights_the_terms_read_are_above_the_terrain_under_them():
    """On stairs down (every platform sunk 0.4 m or more) the G1's pelvis and soles stand as
    high above the ground as on flat ground: the base-height terms and the feet's heights read
    the terrain under them. Its feet, which meet Menagerie's floor through explicit pairs, stand
    on the terrain: half a second holding the pose ends as on flat ground."""
    import json

    from labcli.envs.mdp import config as c
    from labcli.envs.mdp import feet, terminations
    from labcli.gym import make_env

    down = {**TERRAIN, "types": {"down": {"type": "pyramid_stairs", "platform": 1.0,
                                          "inverted": True, "step_height": [0.1, 0.2]}}}
    heights = {}
    for name, terrain in (("flat", None), ("down", down)):
        sets = ["env.observation_noise=false"]
        sets += [] if terrain is None else ["env.terrain=" + json.dumps(terrain)]
        env = make_env("g1-flat", num_envs=4, seed=0, overrides=sets)
        env.reset()
        task = env.task
        (soles,) = [s for s in task._shared.values() if isinstance(s, feet.FootSites)]
        heights[name] = (task.base_height().clone(), soles.heights().clone())
        if terrain is not None:
            # Every platform is 0.4 m or more below z = 0: so is the pelvis below its height
            # on flat ground.
            assert (task.robot.root_height < heights["flat"][0] - 0.3).all()
            fell = terminations.root_height_below_minimum(task, c.BaseHeightBelow(
                minimum_height=0.2))
            assert not fell.any()
        for _ in range(25):
            env.step(torch.zeros(4, len(task.action_names)))
        heights[name] += (task.base_height().clone(),)
    for flat, on_stairs in zip(heights["flat"][:2], heights["down"][:2], strict=True):
        assert torch.allclose(on_stairs, flat, atol=1e-3)
    assert torch.allclose(heights["down"][2], heights["flat"][2], atol=0.02)


def test_config_show_draws_a_tasks_terrain_with_its_settings(tmp_path):
    from typer.testing import CliRunner

    from labcli.commands.app import app

    out = tmp_path / "terrain.png"
    result = CliRunner().invoke(app, [
        "config", "show", "--task", "go1-rough", "--framework", "rsl_rl", "--terrain", str(out),
        "--set", "env.terrain.rows=2", "--set", "env.terrain.cols=6"])
    assert result.exit_code == 0, result.output
    assert "rows: 2" in result.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    flat = CliRunner().invoke(app, ["config", "show", "--task", "go1-flat", "--framework",
                                    "rsl_rl", "--terrain", str(tmp_path / "flat.png")])
    assert flat.exit_code == 2
    assert "error: task 'go1-flat' has no terrain (env.terrain)" in flat.output
    assert not (tmp_path / "flat.png").exists()


def test_a_robot_at_the_terrains_edge_ends_its_episode_as_a_time_out():
    import json

    from labcli.gym import make_env

    # go1-rough's own types left out (null), TERRAIN's two in their place.
    types = {**dict.fromkeys(["stairs", "stairs_down", "boxes", "rough", "slope",
                              "slope_down"]), **TERRAIN["types"]}
    env = make_env("go1-rough", num_envs=4, seed=0, overrides=[
        "env.observation_noise=false", "env.terrain=" + json.dumps({**TERRAIN, "types": types})])
    assert sorted(env.task.terrain.columns) == ["flat", "stairs"]
    env.reset()
    assert list(env.task.terminations()) == ["base_contact"]  # the time-out is not a failure
    state = env.get_state()
    # Grid 3 × 4 m by 2 × 4 m in a 1 m border: |x| up to 7 m, |y| up to 5 m; 0.3 m margin.
    state["qpos"][:, :2] = torch.tensor([[6.8, 0.0], [6.6, 0.0], [0.0, -4.8], [0.0, 4.6]],
                                        dtype=state["qpos"].dtype)
    env.set_state(state)
    _, _, terminated, truncated, _ = env.step(torch.zeros(4, 12))
    assert truncated.tolist() == [True, False, True, False]
    assert not terminated.any()


@needs_menagerie("unitree_go1")
def test_upright_against_the_terrain_is_square_to_its_slope():
    from labcli.envs.mdp import config as c
    from labcli.envs.mdp import rewards

    types = {"slope": {"type": "pyramid_slope", "platform": 1.0, "slope": [0.3, 0.3]}}
    env = _go1_on_terrain(types=types, cols=1)
    task = env.task
    grid = task.terrain
    x0, y0, _ = grid.origins[1, 0].tolist()
    # Half-way down the slope's +x face it falls 0.3 m a metre along x.
    on_slope = torch.tensor([[x0 + 1.2, y0]] * 8, dtype=torch.float64)
    expected = torch.tensor([0.3, 0.0, 1.0], dtype=torch.float64) / (1 + 0.3**2) ** 0.5
    assert torch.allclose(grid.normal(on_slope, 0.3), expected.expand(8, 3), atol=1e-6)
    terrain = c.FlatOrientationL2(weight=-1.0, reference="terrain")
    gravity = c.FlatOrientationL2(weight=-1.0)

    def level_at(xy: torch.Tensor) -> None:  # the robots' roots moved there, upright
        state = env.get_state()
        state["qpos"][:, :2] = xy
        state["qpos"][:, 3:7] = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
        env.set_state(state)
        task.update()

    # At the platform's centre the ground under the base is level, as the world.
    level_at(torch.tensor([[x0, y0]] * 8, dtype=torch.float64))
    assert torch.allclose(rewards.flat_orientation_l2(task, terrain),
                          rewards.flat_orientation_l2(task, gravity), atol=1e-12)
    # On the slope, still level: tilted from the terrain's normal by the slope.
    level_at(on_slope)
    assert torch.allclose(rewards.flat_orientation_l2(task, terrain),
                          torch.full((8,), 0.3**2 / (1 + 0.3**2), dtype=torch.float64),
                          atol=1e-6)


def test_a_rough_run_reports_its_level_and_plays_the_whole_grid_without_the_curriculum(tmp_path):
    import io
    import json

    from rich.console import Console

    from labcli.runs import play, training

    # go1-rough's stairs and rough ground on TERRAIN's small grid (settings merge into the
    # task's: its other types are left out by name).
    small = {**TERRAIN, "types": {"stairs": TERRAIN["types"]["stairs"],
                                  "rough": {"platform": 1.0}, "stairs_down": None,
                                  "boxes": None, "slope": None, "slope_down": None}}
    outcome = training.train(
        "go1-rough", "rsl_rl", num_envs=8, max_iterations=2, logs_dir=tmp_path,
        console=Console(file=io.StringIO()), command=["lab", "test"],
        overrides=["env.terrain=" + json.dumps(small), "env.episode_length_s=0.5",
                   "agent.num_steps_per_env=16"])
    # Every env ended an episode (0.5 s of 0.08 s steps): a level, 0 or 1, was logged.
    assert 0.0 <= outcome.summary["terrain_level"] <= 1.0
    # As Isaac Lab's _PLAY configs: no curriculum, so every row's patch is of a random
    # difficulty, and `--set` may change the terrain (here, keep the stairs only).
    loaded = play.load(run_dir=outcome.run.dir, overrides=["env.terrain.types.rough=null"])
    try:
        grid = loaded.env.task.terrain
        assert not grid.cfg.curriculum and grid.columns == ["stairs", "stairs"]
    finally:
        loaded.env.close()
    with pytest.raises(Exception, match="cannot change a run"):
        play.load(run_dir=outcome.run.dir, overrides=["env.decimation=2"])


def test_the_terrain_keeps_the_robots_scale_and_lights_all_of_it_without_shadows():
    from labcli.envs.render.scene import SceneRenderer

    plain = mujoco.MjModel.from_xml_path(str(GO1))
    model, _ = _build(_small())
    # MuJoCo clips what is nearer a camera than a hundredth of the extent: the grid's ~40 m
    # would hide the robot from the video's camera.
    assert model.stat.extent == pytest.approx(plain.stat.extent)
    assert not model.light_castshadow.any()
    camera = SceneRenderer(model).camera
    assert camera.distance == pytest.approx(1.69, abs=0.01)  # 3.5 × its feet's 0.48 m
    assert camera.distance > 10 * model.vis.map.znear * model.stat.extent
    # A model lit only by a spotlight at its origin gets a sun over the whole grid.
    spec = mujoco.MjSpec.from_file(str(GO1))
    for light in spec.lights:
        spec.delete(light)
    spec.worldbody.add_light(type=mujoco.mjtLightType.mjLIGHT_SPOT, pos=[0, -2, 4])
    tm.apply(spec, _small())
    lit = spec.compile()
    assert lit.nlight == 2 and lit.light_type[1] == mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
