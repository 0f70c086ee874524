"""Terrain, as a task's config holds it (`env.terrain`, `--set env.terrain...`): a grid of
sub-terrain patches, as legged_gym, Isaac Lab and mjlab lay it out. Rows are difficulty levels
(the first row the easiest), columns terrain types in proportions, each patch `size` metres
square, all of it ringed by a flat border. `labcli.envs.mdp.terrain_model` writes it into the
model's MjSpec: height fields (rough, slopes, waves, obstacles, stepping stones) and boxes
(stairs), geometry both backends collide with, the same for the same seed.

Each type's numbers are ranges from the easiest row (difficulty 0) to the hardest (1).

pydantic only (no torch, no MuJoCo), as the terms' configs: a task's config imports it.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

Range = tuple[float, float]


class _SubTerrain(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)

    proportion: float = Field(1.0, gt=0, description="share of the columns of this type")
    platform: float = Field(2.0, ge=0, description="m, the flat square at the centre where "
                            "robots start")


class Flat(_SubTerrain):
    type: Literal["flat"] = "flat"


class RandomRough(_SubTerrain):
    """Uniform noise in height, on a grid coarser than the height field's (legged_gym's)."""

    type: Literal["random_rough"] = "random_rough"
    noise: Range = Field((0.02, 0.10), description="m, the noise's amplitude at difficulty 0 "
                         "and 1")
    step: float = Field(0.02, gt=0, description="m, heights are multiples of this")
    downsampled: float = Field(0.2, gt=0, description="m between drawn heights")


class PyramidSlope(_SubTerrain):
    """Four slopes rising to the platform (falling to it when inverted)."""

    type: Literal["pyramid_slope"] = "pyramid_slope"
    slope: Range = Field((0.0, 0.4), description="rise over run at difficulty 0 and 1")
    inverted: bool = False
    meshes: bool = Field(False, description="the slopes as convex meshes, not a height field: "
                         "MuJoCo Warp meets those as MuJoCo does, where it meets a height "
                         "field's steep cells up to 10 cm too deep (bench/hfield_contacts.py)")


class Wave(_SubTerrain):
    """Sine waves along both axes."""

    type: Literal["wave"] = "wave"
    amplitude: Range = Field((0.0, 0.2), description="m, at difficulty 0 and 1")
    waves: int = Field(4, gt=0, description="periods across the patch")


class PyramidStairs(_SubTerrain):
    """Square rings of steps up to the platform (down to it when inverted), made of boxes."""

    type: Literal["pyramid_stairs"] = "pyramid_stairs"
    step_height: Range = Field((0.05, 0.20), description="m, at difficulty 0 and 1")
    step_width: float = Field(0.3, gt=0, description="m, each step's tread")
    inverted: bool = False


class DiscreteObstacles(_SubTerrain):
    """Rectangular blocks, raised or sunk, scattered over the patch."""

    type: Literal["discrete_obstacles"] = "discrete_obstacles"
    height: Range = Field((0.05, 0.20), description="m, the blocks' height at difficulty 0 "
                          "and 1")
    width: Range = Field((0.5, 2.0), description="m, the smallest and largest block side")
    count: int = Field(20, gt=0)


class SteppingStones(_SubTerrain):
    """Square stones over a pit, the gaps widening with difficulty."""

    type: Literal["stepping_stones"] = "stepping_stones"
    stone: Range = Field((1.0, 0.4), description="m, the stones' side at difficulty 0 and 1")
    gap: Range = Field((0.1, 0.3), description="m between stones at difficulty 0 and 1")
    depth: float = Field(1.0, gt=0, description="m, how far the pit goes down")


SubTerrain = Annotated[Flat | RandomRough | PyramidSlope | Wave | PyramidStairs
                       | DiscreteObstacles | SteppingStones, Field(discriminator="type")]


class TerrainConfig(BaseModel):
    """A grid of `rows` difficulty levels by `cols` columns of the `types`' patches. With
    `curriculum`, robots start on the easier rows and move up (and down) as they walk
    (legged_gym's rule); else each row's patches are of random difficulty."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)

    seed: int = Field(0, ge=0, description="the same seed builds the same terrain")
    size: float = Field(8.0, gt=0, description="m, each patch's side")
    rows: int = Field(10, gt=0, description="difficulty levels")
    cols: int = Field(20, gt=0, description="columns, shared among the types by proportion")
    border: float = Field(20.0, ge=0, description="m of flat ground around the grid")
    horizontal_scale: float = Field(0.1, gt=0, description="m between height-field points")
    vertical_scale: float = Field(0.005, gt=0, description="m, height fields' resolution")
    curriculum: bool = True
    max_start_level: int = Field(5, ge=0, description="with the curriculum, new envs start on "
                                 "a random level up to this")
    difficulty: Range = Field((0.0, 1.0), description="of the first row and the last")
    # A type left out stays in the config as null, so that a run's saved params, merged into
    # its task's defaults again (play, resume), leave it out again.
    types: dict[str, SubTerrain | None] = Field(
        min_length=1, description="by name; a type set to null is left out (--set "
        "env.terrain.types.stairs=null)")

    @property
    def used(self) -> dict[str, SubTerrain]:
        """The types not left out, by name."""
        return {name: sub for name, sub in self.types.items() if sub is not None}

    @model_validator(mode="after")
    def _fits(self) -> TerrainConfig:
        if not self.used:
            raise ValueError("every terrain type is left out (null): keep at least one")
        cells = self.size / self.horizontal_scale
        if abs(cells - round(cells)) > 1e-6 or round(cells) < 4:
            raise ValueError(f"size {self.size} m is not a whole number (at least 4) of "
                             f"horizontal_scale {self.horizontal_scale} m")
        if len(self.used) > self.cols:
            raise ValueError(f"{len(self.used)} terrain types need at least as many columns; "
                             f"cols is {self.cols}")
        for name, sub in self.used.items():
            if sub.platform >= self.size:
                raise ValueError(f"types.{name}.platform {sub.platform} m does not fit a "
                                 f"patch of {self.size} m")
        return self

    def columns(self) -> list[str]:
        """Each column's type: the types' shares of `cols` by proportion, in order, each at
        least one (largest remainders get the columns left)."""
        used = self.used
        total = sum(t.proportion for t in used.values())
        names = list(used)
        exact = [used[n].proportion / total * self.cols for n in names]
        counts = [max(1, int(e)) for e in exact]
        while sum(counts) > self.cols:  # from the most over its share that has a spare
            spare = [i for i in range(len(counts)) if counts[i] > 1]
            counts[max(spare, key=lambda i: counts[i] - exact[i])] -= 1
        while sum(counts) < self.cols:
            counts[max(range(len(counts)), key=lambda i: exact[i] - counts[i])] += 1
        return [name for name, count in zip(names, counts, strict=True) for _ in range(count)]


def rough() -> TerrainConfig:
    """mjlab 1.6.0's ROUGH_TERRAINS_CFG (its rough velocity tasks): a fifth flat, two fifths
    stairs up and down, slopes up to 45°, random roughness and waves, 10 rows of 20 columns of
    8 m patches in a 20 m border. Its roughness is fixed, here it grows with the level."""
    stairs = {"step_height": (0.0, 0.1), "step_width": 0.3, "platform": 3.0}
    return TerrainConfig(types={
        "flat": Flat(proportion=0.2),
        "stairs": PyramidStairs(proportion=0.2, **stairs),
        "stairs_down": PyramidStairs(proportion=0.2, inverted=True, **stairs),
        "slope": PyramidSlope(proportion=0.1, slope=(0.0, 1.0)),
        "slope_down": PyramidSlope(proportion=0.1, slope=(0.0, 1.0), inverted=True),
        "rough": RandomRough(proportion=0.1),
        "waves": Wave(proportion=0.1),
    })
