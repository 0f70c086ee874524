"""A `TerrainConfig` written into a model's MjSpec: each patch a height field, a stack of
boxes or convex meshes, geoms of the world body named `terrain/<n>`, in place of the model's
ground planes (whose contact settings the terrain's geoms take over), and a flat border around
the grid. The grid is centred on the world's origin, rows along x. Built from the config's
seed alone: the same config gives the same geometry, which a resumed or played run rebuilds.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from labcli.envs.mdp import terrain as t

# The terrain's geoms are the world body's own: MuJoCo computes their poses once, not on each
# step as for any other body's (on a 2-core CPU, go1 on stairs stepped 2× faster so).
PREFIX = "terrain/"
BASE = 1.0  # m of solid ground under every patch's lowest point
FLAT_EDGE = 0.25  # m: height-field patches end flat at height 0, to meet their neighbours
COLORS = {"flat": (0.45, 0.47, 0.50, 1), "random_rough": (0.42, 0.50, 0.38, 1),
          "pyramid_slope": (0.55, 0.48, 0.38, 1), "wave": (0.38, 0.47, 0.55, 1),
          "pyramid_stairs": (0.60, 0.56, 0.50, 1), "discrete_obstacles": (0.50, 0.42, 0.48, 1),
          "stepping_stones": (0.48, 0.52, 0.45, 1)}
BORDER_RGBA = (0.3, 0.3, 0.3, 1)
# The contact bit by which geoms that met the ground through explicit pairs meet the terrain.
TERRAIN_BIT = 1 << 3
CONTACT = ("contype", "conaffinity", "condim", "priority", "friction", "solmix", "solref",
           "solimp", "margin", "gap")


@dataclass(frozen=True)
class Terrain:
    """What the tasks need of a built terrain: each patch's start point (the centre of its
    platform, on the surface) [rows, cols, 3], each column's type name, and each patch's
    difficulty [rows, cols]."""

    origins: np.ndarray
    columns: list[str]
    difficulty: np.ndarray


def apply(spec: mujoco.MjSpec, cfg: t.TerrainConfig) -> Terrain:
    """Replace the model's ground planes with `cfg`'s terrain; returns where each patch is."""
    contact = _take_ground(spec)
    _keep_the_robots_scale(spec)
    body = spec.worldbody
    first = len(body.geoms)
    rng = np.random.default_rng(cfg.seed)
    columns = cfg.columns()
    rows, cols = cfg.rows, len(columns)
    origins = np.zeros((rows, cols, 3))
    difficulty = np.zeros((rows, cols))
    lo, hi = cfg.difficulty
    for col, name in enumerate(columns):
        sub = cfg.used[name]
        for row in range(rows):
            if cfg.curriculum:
                level = lo + (hi - lo) * row / max(rows - 1, 1)
            else:
                level = float(rng.uniform(lo, hi))
            centre = np.array([(row + 0.5 - rows / 2) * cfg.size,
                               (col + 0.5 - cols / 2) * cfg.size])
            top = _patch(spec, body, cfg, sub, level, centre, rng, f"{name}_{row}_{col}")
            origins[row, col] = (*centre, top)
            difficulty[row, col] = level
    _border(body, cfg, rows * cfg.size, cols * cfg.size)
    for i, geom in enumerate(list(body.geoms)[first:]):
        geom.name = f"{PREFIX}{i}"
        for attr in CONTACT:
            if attr in contact:
                setattr(geom, attr, contact[attr])
    return Terrain(origins, columns, difficulty)


def _keep_the_robots_scale(spec: mujoco.MjSpec) -> None:
    """The scene's extent stays the robot's: MuJoCo clips what is nearer a camera than a
    hundredth of it, so a grid's 300 m extent would hide a robot from a camera 2 m away. Its
    lights cast no shadows, whose map would spread over the whole grid in jagged bands; and
    the sun shines on all of it where no light does (a spotlight placed at the model's origin
    leaves a robot 80 m away in the dark)."""
    if np.isnan(spec.stat.extent):
        spec.stat.extent = spec.compile().stat.extent
    for light in spec.lights:
        light.castshadow = False
    if not any(light.type == mujoco.mjtLightType.mjLIGHT_DIRECTIONAL for light in spec.lights):
        spec.worldbody.add_light(type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, dir=[0, 0, -1],
                                 pos=[0, 0, 10], diffuse=[0.6, 0.6, 0.6], castshadow=False)


def _take_ground(spec: mujoco.MjSpec) -> dict:
    """Delete the world's ground planes; returns the first one's contact settings, with which
    the terrain's geoms collide. A model that collides through explicit pairs with its plane
    (MuJoCo Menagerie's MJX scenes: feet and hands against the floor, every geom's contype 0)
    collides its geoms of those pairs with the terrain instead (`_pairs_to_terrain`)."""
    planes = [g for g in spec.worldbody.geoms if g.type == mujoco.mjtGeom.mjGEOM_PLANE]
    contact = {attr: _copy(getattr(planes[0], attr)) for attr in CONTACT} if planes else {}
    names = {plane.name for plane in planes if plane.name}
    if names and _pairs_to_terrain(spec, names, contact.get("priority", 0)):
        # The plane's own bits stay: geoms that met it by contype meet the terrain too.
        contact["conaffinity"] = contact.get("conaffinity", 0) | TERRAIN_BIT
    for plane in planes:
        spec.delete(plane)
    return contact


def _pairs_to_terrain(spec: mujoco.MjSpec, planes: set[str], priority: int) -> bool:
    """Each geom paired with a deleted plane collides with the terrain by its own bit (the
    terrain's conaffinity, no other geom's), taking the pair's contact settings as its own at
    a priority above the terrain's, so that MuJoCo uses them for those contacts. The pairs go.
    Returns whether there were any."""
    pairs = [p for p in spec.pairs if p.geomname1 in planes or p.geomname2 in planes]
    for pair in pairs:
        name = pair.geomname2 if pair.geomname1 in planes else pair.geomname1
        geom = spec.geom(name)
        geom.contype |= TERRAIN_BIT
        geom.priority = priority + 1
        geom.condim, geom.margin, geom.gap = pair.condim, pair.margin, pair.gap
        geom.solref, geom.solimp = pair.solref.copy(), pair.solimp.copy()
        # A pair's five frictions (two sliding, torsional, two rolling); a geom's three.
        geom.friction = [pair.friction[0], pair.friction[2], pair.friction[3]]
        spec.delete(pair)
    return bool(pairs)


def _copy(value):
    return value.copy() if isinstance(value, np.ndarray) else value


def _patch(spec: mujoco.MjSpec, body: mujoco.MjsBody, cfg: t.TerrainConfig, sub, level: float,
           centre: np.ndarray, rng: np.random.Generator, name: str) -> float:
    """One patch centred at `centre`; returns its platform's height."""
    rgba = COLORS[sub.type]
    if isinstance(sub, t.PyramidStairs):
        return _stairs(body, cfg, sub, level, centre, rgba)
    if isinstance(sub, t.Flat):
        _box(body, centre, cfg.size / 2, cfg.size / 2, 0.0, -BASE, rgba)
        return 0.0
    if isinstance(sub, t.PyramidSlope) and sub.meshes:
        return _pyramid(spec, body, cfg, sub, level, centre, rgba, name)
    heights = _heights(cfg, sub, level, rng)
    low, high = float(heights.min()), float(heights.max())
    span = max(high - low, cfg.vertical_scale)
    n = heights.shape[0]
    half = cfg.size / 2
    spec.add_hfield(name=name, size=[half, half, span, BASE], nrow=n, ncol=n,
                    userdata=((heights - low) / span).ravel().tolist())
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname=name,
                  pos=[centre[0], centre[1], low], rgba=rgba)
    middle = n // 2
    return float(heights[middle, middle])


def _heights(cfg: t.TerrainConfig, sub, level: float, rng: np.random.Generator) -> np.ndarray:
    """The patch's heights (m) on its (n × n) grid of `horizontal_scale` spacing, rows along y:
    MuJoCo's height-field layout. Edges flat at 0 (`FLAT_EDGE`), and the platform too (a
    slope's is its top), quantized to `vertical_scale`."""
    n = round(cfg.size / cfg.horizontal_scale) + 1
    coords = np.linspace(-cfg.size / 2, cfg.size / 2, n)
    x, y = np.meshgrid(coords, coords)  # x varies along a row, y down the columns
    platform = sub.platform / 2
    inner = cfg.size / 2 - FLAT_EDGE
    ring = np.maximum(np.abs(x), np.abs(y))  # distance to the centre, in squares
    if isinstance(sub, t.RandomRough):
        amplitude = _lerp(sub.noise, level)
        coarse = max(2, round(cfg.size / sub.downsampled) + 1)
        steps = np.arange(0.0, amplitude + 1e-9, sub.step)
        drawn = rng.choice(steps, size=(coarse, coarse))
        heights = _resample(drawn, n)
    elif isinstance(sub, t.PyramidSlope):
        rise = _slope_rise(cfg, sub, level)
        heights = rise * np.clip((inner - ring) / max(inner - platform, 1e-9), 0.0, 1.0)
        heights = -heights if sub.inverted else heights
    elif isinstance(sub, t.Wave):
        amplitude = _lerp(sub.amplitude, level)
        k = 2 * np.pi * sub.waves / cfg.size
        heights = amplitude / 2 * (np.sin(k * x) + np.cos(k * y))
    elif isinstance(sub, t.DiscreteObstacles):
        heights = np.zeros((n, n))
        height = _lerp(sub.height, level)
        cells = cfg.horizontal_scale
        for _ in range(sub.count):
            rows, cols = (rng.uniform(*sub.width, size=2) / cells).astype(int) + 1
            r, c = rng.integers(0, n - rows), rng.integers(0, n - cols)
            heights[r:r + rows, c:c + cols] = rng.choice([-height, height])
    elif isinstance(sub, t.SteppingStones):
        stone, gap = _lerp(sub.stone, level), _lerp(sub.gap, level)
        pitch = stone + gap
        on_x = np.mod(x + stone / 2, pitch) < stone
        on_y = np.mod(y + stone / 2, pitch) < stone
        heights = np.where(on_x & on_y, 0.0, -sub.depth)
    else:  # a new type must say how it is built
        raise TypeError(f"no height field for terrain type {sub.type!r}")
    if not isinstance(sub, t.PyramidSlope):  # a slope's platform is its flat top already
        heights = np.where(ring <= platform, 0.0, heights)
    heights = np.where(ring >= inner, 0.0, heights)
    return np.round(heights / cfg.vertical_scale) * cfg.vertical_scale


def _resample(coarse: np.ndarray, n: int) -> np.ndarray:
    """`coarse` (k × k) bilinearly onto n × n points spanning the same square."""
    k = coarse.shape[0]
    at = np.linspace(0, k - 1, n)
    i = np.minimum(at.astype(int), k - 2)
    f = at - i
    rows = coarse[i] * (1 - f)[:, None] + coarse[i + 1] * f[:, None]
    return rows[:, i] * (1 - f)[None, :] + rows[:, i + 1] * f[None, :]


def _stairs(body: mujoco.MjsBody, cfg: t.TerrainConfig, sub: t.PyramidStairs, level: float,
            centre: np.ndarray, rgba) -> float:
    """Square steps from the patch's flat edge to the platform. Up: nested solid squares, each a
    step higher and narrower. Down: square rings, each a step lower, round a sunk platform."""
    rise = _lerp(sub.step_height, level)
    half = cfg.size / 2
    outer = half - FLAT_EDGE
    count = max(0, int((outer - sub.platform / 2) / sub.step_width))
    if not sub.inverted:
        _box(body, centre, half, half, 0.0, -BASE, rgba)
        for i in range(count):
            side = outer - i * sub.step_width
            _box(body, centre, side, side, (i + 1) * rise, -BASE, rgba)
        return count * rise
    # The mirror image of the way up: the ring between squares i and i + 1 a step lower each.
    bottom = -count * rise - BASE
    _ring(body, centre, half, outer, 0.0, bottom, rgba)
    for i in range(count - 1):
        side = outer - i * sub.step_width
        _ring(body, centre, side, side - sub.step_width, -(i + 1) * rise, bottom, rgba)
    side = outer - max(count - 1, 0) * sub.step_width
    _box(body, centre, side, side, -count * rise, bottom, rgba)
    return -count * rise


def _pyramid(spec: mujoco.MjSpec, body: mujoco.MjsBody, cfg: t.TerrainConfig,
             sub: t.PyramidSlope, level: float, centre: np.ndarray, rgba, name: str) -> float:
    """The slope's surface (`_heights`' without its quantization) of convex meshes. Up: a
    frustum from the flat edge to the platform on flat ground. Down: four wedges, each falling
    from the flat edge to the sunk platform's side, on a floor at the platform's height, in a
    ring at the edge's."""
    half = cfg.size / 2
    inner = half - FLAT_EDGE
    platform = sub.platform / 2
    rise = _slope_rise(cfg, sub, level)
    if rise <= 0:
        _box(body, centre, half, half, 0.0, -BASE, rgba)
        return 0.0
    square = np.array([(-1, -1), (1, -1), (1, 1), (-1, 1)], dtype=float)
    if not sub.inverted:
        _box(body, centre, half, half, 0.0, -BASE, rgba)
        _mesh(spec, body, name, centre, [(*inner * square[k], 0.0) for k in range(4)]
              + [(*platform * square[k], rise) for k in range(4)], rgba)
        return rise
    _box(body, centre, half, half, -rise, -rise - BASE, rgba)
    _ring(body, centre, half, inner, 0.0, -rise, rgba)
    # Each wedge spans its side's whole width, past the diagonals where its neighbours' rise
    # above it: the pit's surface is the highest of the four, with no seam between them.
    for k in range(4):
        ends = (k, (k + 1) % 4)
        outward = (square[ends[0]] + square[ends[1]]) / 2
        _mesh(spec, body, f"{name}_{k}", centre,
              [(*(inner * square[i] - (inner - platform) * outward), -rise) for i in ends]
              + [(*inner * square[i], z) for i in ends for z in (0.0, -rise)], rgba)
    return -rise


def _mesh(spec: mujoco.MjSpec, body: mujoco.MjsBody, name: str, centre, vertices,
          rgba) -> None:
    """A convex mesh (the hull of `vertices`, relative to the patch's centre at height 0)."""
    spec.add_mesh(name=name, uservert=np.asarray(vertices, dtype=float).ravel().tolist())
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name,
                  pos=[centre[0], centre[1], 0.0], rgba=rgba)


def _box(body: mujoco.MjsBody, centre, half_x: float, half_y: float, top: float,
         bottom: float, rgba) -> None:
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[half_x, half_y, (top - bottom) / 2],
                  pos=[centre[0], centre[1], (top + bottom) / 2], rgba=rgba)


def _ring(body: mujoco.MjsBody, centre, outer: float, inner: float, top: float, bottom: float,
          rgba) -> None:
    """A square ring of four boxes between half-widths `inner` and `outer`."""
    width = (outer - inner) / 2
    middle = (outer + inner) / 2
    for sign in (-1, 1):
        _box(body, (centre[0] + sign * middle, centre[1]), width, outer, top, bottom, rgba)
        _box(body, (centre[0], centre[1] + sign * middle), inner, width, top, bottom, rgba)


def _border(body: mujoco.MjsBody, cfg: t.TerrainConfig, length_x: float,
            length_y: float) -> None:
    """Flat ground `cfg.border` wide around the grid (a ring round its centre)."""
    if cfg.border <= 0:
        return
    hx, hy = length_x / 2, length_y / 2
    b = cfg.border
    for sign in (-1, 1):
        _box(body, (sign * (hx + b / 2), 0.0), b / 2, hy + b, 0.0, -BASE, BORDER_RGBA)
        _box(body, (0.0, sign * (hy + b / 2)), hx, b / 2, 0.0, -BASE, BORDER_RGBA)


def _slope_rise(cfg: t.TerrainConfig, sub: t.PyramidSlope, level: float) -> float:
    """How far a slope climbs from the patch's flat edge to its platform: a height field's and
    meshes' alike."""
    return _lerp(sub.slope, level) * (cfg.size / 2 - FLAT_EDGE - sub.platform / 2)


def _lerp(bounds: tuple[float, float], level: float) -> float:
    return bounds[0] + (bounds[1] - bounds[0]) * level


def height_map(model: mujoco.MjModel, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """The terrain's top surface as the compiled model holds it, sampled every `resolution`
    metres over its boxes' and height fields' extent: (heights [ny, nx], extent [x0, x1, y0,
    y1]). Read from the model's geoms, not from the generator: what MuJoCo collides with."""
    geoms = geom_ids(model)
    boxes = [g for g in geoms if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX]
    fields = [g for g in geoms if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_HFIELD]
    meshes = [g for g in geoms if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]
    reach = np.array([np.concatenate(_footprint(model, g)) for g in geoms])
    x0, y0 = reach[:, :2].min(axis=0)
    x1, y1 = reach[:, 2:].max(axis=0)
    xs = np.arange(x0, x1, resolution) + resolution / 2
    ys = np.arange(y0, y1, resolution) + resolution / 2
    heights = np.full((len(ys), len(xs)), np.nan)
    for g in boxes:  # the highest top wins: nested boxes, and a stair's ring over its base
        (lo_x, hi_x), (lo_y, hi_y) = _cells(model, g, xs, ys)
        top = model.geom_pos[g, 2] + model.geom_size[g, 2]
        heights[lo_y:hi_y, lo_x:hi_x] = np.fmax(heights[lo_y:hi_y, lo_x:hi_x], top)
    for g in fields:
        h = model.geom_dataid[g]
        rows, cols = model.hfield_nrow[h], model.hfield_ncol[h]
        start = model.hfield_adr[h]
        data = model.hfield_data[start:start + rows * cols].reshape(rows, cols)
        (lo_x, hi_x), (lo_y, hi_y) = _cells(model, g, xs, ys)
        half_x, half_y, top, _ = model.hfield_size[h]
        cx, cy, cz = model.geom_pos[g]
        c = np.clip(np.round((xs[lo_x:hi_x] - cx + half_x) / (2 * half_x) * (cols - 1)), 0,
                    cols - 1).astype(int)
        r = np.clip(np.round((ys[lo_y:hi_y] - cy + half_y) / (2 * half_y) * (rows - 1)), 0,
                    rows - 1).astype(int)
        heights[lo_y:hi_y, lo_x:hi_x] = cz + data[np.ix_(r, c)] * top
    for g in meshes:  # over the boxes they stand on
        (lo_x, hi_x), (lo_y, hi_y) = _cells(model, g, xs, ys)
        x, y = np.meshgrid(xs[lo_x:hi_x], ys[lo_y:hi_y])
        region = heights[lo_y:hi_y, lo_x:hi_x]
        heights[lo_y:hi_y, lo_x:hi_x] = np.fmax(region, _hull_top(model, g, x, y))
    return heights, np.array([x0, x1, y0, y1])


def _mesh_vertices(model: mujoco.MjModel, g: int) -> np.ndarray:
    """Mesh geom `g`'s vertices in the world (a terrain geom's pose is its own: world body)."""
    mesh = model.geom_dataid[g]
    start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, model.geom_quat[g])
    return model.mesh_vert[start:start + count] @ rotation.reshape(3, 3).T + model.geom_pos[g]


def _hull_top(model: mujoco.MjModel, g: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The top of convex mesh geom `g` over points (x, y), NaN where it is not over them: the
    lowest of its upward faces' planes, where the point is inside its upright faces and that
    top is not below the highest of its downward faces'."""
    mesh = model.geom_dataid[g]
    start, count = model.mesh_faceadr[mesh], model.mesh_facenum[mesh]
    vertices = _mesh_vertices(model, g)
    a, b, c = (vertices[model.mesh_face[start:start + count, i]] for i in range(3))
    normal = np.cross(b - a, c - a)  # outward
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    n, p = normal[:, None, None], a[:, None, None]
    across = n[..., 0] * (x - p[..., 0]) + n[..., 1] * (y - p[..., 1])  # [faces, ...]
    up, down = normal[:, 2] > 1e-6, normal[:, 2] < -1e-6  # float32 vertices: upright ~1e-8
    plane = np.divide(p[..., 2] * n[..., 2] - across, n[..., 2],
                      out=np.zeros_like(across), where=(up | down)[:, None, None])
    top, bottom = plane[up].min(axis=0), plane[down].max(axis=0)
    inside = (top >= bottom - 1e-6) & (across[~(up | down)] <= 1e-6).all(axis=0)
    return np.where(inside, top, np.nan)


def geom_ids(model: mujoco.MjModel) -> list[int]:
    """The terrain's geoms in a compiled model."""
    return [g for g in range(model.ngeom) if model.geom(g).name.startswith(PREFIX)]


def _footprint(model: mujoco.MjModel, g: int) -> tuple[np.ndarray, np.ndarray]:
    """The lowest and highest (x, y) of terrain geom `g` (boxes and fields are not turned)."""
    if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
        vertices = _mesh_vertices(model, g)[:, :2]
        return vertices.min(axis=0), vertices.max(axis=0)
    if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_HFIELD:
        half = model.hfield_size[model.geom_dataid[g], :2]
    else:
        half = model.geom_size[g, :2]
    return model.geom_pos[g, :2] - half, model.geom_pos[g, :2] + half


def _cells(model: mujoco.MjModel, g: int, xs: np.ndarray, ys: np.ndarray):
    """The sample indices inside geom `g`'s footprint, as (x range, y range)."""
    lo, hi = _footprint(model, g)
    return ((int(np.searchsorted(xs, lo[0])), int(np.searchsorted(xs, hi[0]))),
            (int(np.searchsorted(ys, lo[1])), int(np.searchsorted(ys, hi[1]))))


def save_preview(model: mujoco.MjModel, cfg: t.TerrainConfig, output: Path,
                 resolution: float = 0.05) -> None:
    """A top view of the model's terrain (built from `cfg`) as a PNG, coloured by height
    (`height_map`): rows (difficulty) up the image, each column labelled with its type.
    Written atomically."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from labcli import files

    heights, (x0, x1, y0, y1) = height_map(model, resolution)
    columns = cfg.columns()
    rows, cols = cfg.rows, len(columns)
    fig = Figure(figsize=(max(6.0, cols * 0.6), max(4.0, rows * 0.45)), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    # Columns across, rows up: the grid is wider than deep.
    image = ax.imshow(heights.T, origin="lower", extent=(y0, y1, x0, x1), cmap="terrain",
                      interpolation="nearest")
    ax.set_xticks([(c + 0.5 - cols / 2) * cfg.size for c in range(cols)], columns,
                  rotation=60, fontsize="small")
    lo, hi = cfg.difficulty
    ax.set_yticks([(r + 0.5 - rows / 2) * cfg.size for r in range(rows)],
                  [f"{lo + (hi - lo) * r / max(rows - 1, 1):.2f}" if cfg.curriculum else str(r)
                   for r in range(rows)], fontsize="small")
    margin = min(cfg.border, 1.0)  # the grid, not the whole border
    ax.set_xlim(-cols * cfg.size / 2 - margin, cols * cfg.size / 2 + margin)
    ax.set_ylim(-rows * cfg.size / 2 - margin, rows * cfg.size / 2 + margin)
    ax.set_xlabel("terrain type (y)")
    ax.set_ylabel("difficulty (x)" if cfg.curriculum else "row, of random difficulty (x)")
    ax.set_title(f"terrain, seed {cfg.seed}: {rows} × {cols} patches of {cfg.size:g} m")
    fig.colorbar(image, ax=ax, label="height (m)", shrink=0.8)
    fig.tight_layout()
    with files.staged(output) as tmp:
        fig.savefig(tmp, format="png")
