"""Do MuJoCo Warp and MuJoCo's C engine meet a task's height-field terrain alike?

  python bench/hfield_contacts.py [--task go1-rough] [--radius 0.023] [--places 256]
                                  [--depth 0.005] [--set env.KEY=VALUE ...]

A sphere of `--radius` (a foot's) is put at `--places` random points of each height-field type
of the task's terrain (its patches of every difficulty, platforms left out), at the height at
which MuJoCo finds it `--depth` into the ground, and both engines compute its contacts there
(MuJoCo Warp on CUDA where torch sees a GPU, else on warp's CPU device). Per type: the share
of places where MuJoCo Warp's deepest contact is more than 5 mm deeper than MuJoCo's, the
median and largest excess, and the share of those whose contact normal MuJoCo Warp made
vertical where MuJoCo's leans more than 30 degrees. MuJoCo Warp (4.0.0) turns a contact with
a height-field prism's side into one along the vertical, as deep as the prism's top above the
sphere: where the ground steps by more than the sphere's radius between two points of the
field, a foot against the step is pushed up by the step's height. `--set
env.terrain.types.slope.meshes=true` (and `slope_down`'s) measures the slopes built of convex
meshes instead.
"""

from __future__ import annotations

import argparse
import statistics

import mujoco
import numpy as np
import torch

from labcli.envs.mdp import terrain_model
from labcli.plugins import registry
from labcli.runs import config

EXCESS = 0.005  # m deeper in MuJoCo Warp than in MuJoCo: a disagreement
LEANING = np.cos(np.radians(30.0))  # a normal's z below this leans more than 30 degrees
VERTICAL = np.cos(np.radians(1.0))


def terrain_with_sphere(task: str, sets: list[str], radius: float):
    """The task's terrain (a world of it alone) with a free sphere, and where each patch is."""
    env_cfg, _ = config.resolve(registry.get_task(task), registry.get_framework("rsl_rl"),
                                overrides=sets)
    if getattr(env_cfg, "terrain", None) is None:
        raise SystemExit(f"{task} has no terrain: pick a rough task (go1-rough, g1-rough)")
    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 0.1])
    patches = terrain_model.apply(spec, env_cfg.terrain)
    body = spec.worldbody.add_body(name="foot")
    body.add_freejoint()
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0])
    return spec.compile(), env_cfg.terrain, patches


def places(terrain_cfg, patches, count: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """`count` random (x, y) per type but the box-built ones, off the platforms and flat
    edges (the slopes' meshes, where `meshes` asks for them, are measured as the fields are)."""
    out = {}
    for name, sub in terrain_cfg.used.items():
        if sub.type in ("flat", "pyramid_stairs"):  # boxes, not height fields
            continue
        cols = [i for i, column in enumerate(patches.columns) if column == name]
        picked = np.c_[rng.integers(0, terrain_cfg.rows, count), rng.choice(cols, count)]
        half = terrain_cfg.size / 2 - terrain_model.FLAT_EDGE
        inner = sub.platform / 2
        offsets = rng.uniform(-half, half, (count, 2))
        # off the platform: push points inside it out along their larger coordinate
        ring = np.abs(offsets).max(axis=1)
        scale = np.where(ring < inner, (inner + (half - inner) * rng.uniform(0, 1, count))
                         / np.maximum(ring, 1e-9), 1.0)
        offsets *= scale[:, None]
        centres = patches.origins[picked[:, 0], picked[:, 1], :2]
        out[name] = centres + offsets
    return out


def deepest_c(model, data, xy, z) -> tuple[float, np.ndarray]:
    data.qpos[:3] = (*xy, z)
    data.qpos[3:7] = (1, 0, 0, 0)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_collision(model, data)
    if data.ncon == 0:
        return np.inf, np.zeros(3)
    k = int(np.argmin(data.contact.dist[:data.ncon]))
    return float(data.contact.dist[k]), data.contact.frame[k, :3].copy()


def height_at_depth(model, data, xy, depth: float) -> float:
    """The sphere's centre height at which MuJoCo's deepest contact is `depth` deep."""
    low, high = -5.0, 5.0  # the terrain's heights lie well within
    for _ in range(50):
        z = 0.5 * (low + high)
        if deepest_c(model, data, xy, z)[0] < -depth:
            low = z
        else:
            high = z
    return high


def compare(model, points: dict[str, np.ndarray], depth: float) -> list[dict]:
    import mujoco_warp as mjw
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    device = "cuda:0" if torch.cuda.is_available() else "cpu"
    data = mujoco.MjData(model)
    with wp.ScopedDevice(device):
        m = mjw.put_model(model)  # once: the same terrain for every type's places
    rows = []
    for name, xy in points.items():
        n = len(xy)
        z = np.array([height_at_depth(model, data, p, depth) for p in xy])
        c = [deepest_c(model, data, p, h) for p, h in zip(xy, z, strict=True)]
        qpos = np.zeros((n, 7), np.float32)
        qpos[:, :2], qpos[:, 2], qpos[:, 3] = xy, z, 1.0
        with wp.ScopedDevice(device):
            d = mjw.make_data(model, nworld=n, nconmax=n * 32, njmax=n * 128)
            d.qpos.assign(wp.array(qpos))
            mjw.kinematics(m, d)
            mjw.collision(m, d)
            count = int(d.nacon.numpy()[0])
            dist = d.contact.dist.numpy()[:count]
            world = d.contact.worldid.numpy()[:count]
            normal = d.contact.frame.numpy()[:count, 0]
        excess, turned = [], 0
        for i in range(n):
            mine = np.flatnonzero(world == i)
            k = mine[np.argmin(dist[mine])] if len(mine) else None
            warp_dist = dist[k] if k is not None else np.inf
            extra = c[i][0] - warp_dist
            if extra > EXCESS:
                excess.append(extra)
                if normal[k][2] > VERTICAL and c[i][1][2] < LEANING:
                    turned += 1
        rows.append({"type": name, "places": n, "apart": len(excess),
                     "median": statistics.median(excess) if excess else 0.0,
                     "largest": max(excess, default=0.0), "turned": turned})
    print(f"MuJoCo Warp on {device}; a sphere {depth * 1000:g} mm into the ground in MuJoCo")
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", default="go1-rough")
    p.add_argument("--set", action="append", default=[], dest="sets", metavar="env.KEY=VALUE")
    p.add_argument("--radius", type=float, default=0.023, help="m (Menagerie's Go1 feet)")
    p.add_argument("--places", type=int, default=256, help="per terrain type")
    p.add_argument("--depth", type=float, default=0.005, help="m into the ground in MuJoCo")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args()
    model, terrain_cfg, patches = terrain_with_sphere(a.task, a.sets, a.radius)
    points = places(terrain_cfg, patches, a.places, np.random.default_rng(a.seed))
    rows = compare(model, points, a.depth)
    print("| terrain type | places | MuJoCo Warp's deepest > 5 mm deeper | median / largest "
          "excess, mm | of those, made vertical where MuJoCo's leans > 30° |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for r in rows:
        print(f"| {r['type']} | {r['places']} | {r['apart']} ({r['apart'] / r['places']:.0%}) | "
              f"{r['median'] * 1000:.1f} / {r['largest'] * 1000:.1f} | {r['turned']} |")


if __name__ == "__main__":
    main()
