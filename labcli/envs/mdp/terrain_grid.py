"""The terrain as a robot task uses it while it runs: where each env starts (its patch's level
and type), legged_gym's curriculum that moves envs up and down the levels, and the terrain's
height under any point, for the height scan.

Everything is read from the compiled model (`terrain_model.height_map`) and the config, so a
played or resumed run rebuilds it from its params alone. Heights are looked up in a map of the
terrain's top surface sampled every `MAP_RESOLUTION` metres (legged_gym's `measured_heights`)
rather than cast as rays: the terrain is static and each env's world holds only its robot, so
a vertical ray's hit is that map's height, and the lookup is a few tensor ops that run
unchanged on both backends and inside the GPU step's CUDA graph.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from labcli.envs.mdp import terrain_model as tm
from labcli.envs.mdp.terrain import TerrainConfig

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask

MAP_RESOLUTION = 0.05  # m: half the height fields' spacing, a tenth of a Go1's foot step


class TerrainGrid:
    """Per env: its level (row) and type (column) on the grid, and where its episode began.
    `reset(mask)` runs the curriculum for the envs whose episode ended (after the first) and
    moves the robots of `mask` onto their patches; `heights(xy)` is the terrain under points."""

    carried = ("levels", "types", "start", "walked", "started")

    def __init__(self, task: RobotTask, cfg: TerrainConfig, episode_s: float):
        self.cfg, self.robot = cfg, task.robot
        n, dev, dtype = task.num_envs, task.sim.qpos.device, task.sim.qpos.dtype
        heights, extent = tm.height_map(task.model, MAP_RESOLUTION)
        self.map = torch.as_tensor(heights, dtype=dtype, device=dev)
        self.corner = torch.as_tensor(extent[[0, 2]], dtype=dtype, device=dev)
        self.columns = cfg.columns()
        self.rows, self.cols = cfg.rows, len(self.columns)
        centres = torch.stack(torch.meshgrid(
            (torch.arange(self.rows, device=dev, dtype=dtype) + 0.5 - self.rows / 2) * cfg.size,
            (torch.arange(self.cols, device=dev, dtype=dtype) + 0.5 - self.cols / 2) * cfg.size,
            indexing="ij"), dim=-1)
        self.origins = torch.cat([centres, self.heights(centres)[..., None]], dim=-1)
        self.episode_s = episode_s
        # Types spread evenly over the envs (legged_gym): the columns hold the proportions.
        self.types = torch.arange(n, device=dev) * self.cols // n
        self.levels = torch.zeros(n, dtype=torch.long, device=dev)
        self.start = torch.zeros(n, 2, dtype=dtype, device=dev)
        self.walked = torch.zeros(n, dtype=dtype, device=dev)
        self.started = torch.zeros(n, dtype=torch.bool, device=dev)
        self.task = task
        self._drawn = torch.empty(n, 2, dtype=dtype, device=dev)
        self._command: torch.Tensor | None = None
        # Per type: which columns are of it.
        self._of_type = {name: torch.tensor([c == name for c in self.columns], device=dev)
                         for name in dict.fromkeys(self.columns)}

    def follow_command(self, command: torch.Tensor) -> None:
        """The velocity command `[n, >=2]` whose distance the curriculum asks the envs to walk
        (a velocity command term registers its own)."""
        self._command = command

    def heights(self, xy: torch.Tensor) -> torch.Tensor:
        """The terrain's height under each point `[..., 2]` (world x, y); off the map, its
        nearest edge's."""
        index = torch.floor((xy - self.corner) / MAP_RESOLUTION).long()  # the sample's cell
        column = index[..., 0].clamp(0, self.map.shape[1] - 1)  # the map is [y, x]
        row = index[..., 1].clamp(0, self.map.shape[0] - 1)
        return self.map[row, column]

    def normal(self, xy: torch.Tensor, span: float) -> torch.Tensor:
        """The terrain's unit normal `[n, 3]` under points `[n, 2]`: its slope taken `span`
        metres each way along x and y (a stair's edge is averaged over the span)."""
        dx, dy = self.task.constant([span, 0.0]), self.task.constant([0.0, span])
        slope_x = (self.heights(xy + dx) - self.heights(xy - dx)) / (2 * span)
        slope_y = (self.heights(xy + dy) - self.heights(xy - dy)) / (2 * span)
        normal = torch.stack((-slope_x, -slope_y, torch.ones_like(slope_x)), dim=1)
        return normal / torch.linalg.vector_norm(normal, dim=1, keepdim=True)

    def after_step(self) -> None:
        torch.linalg.vector_norm(self.robot.root_xy - self.start, dim=1, out=self.walked)

    def reset(self, mask: torch.Tensor) -> None:
        """Before the terms' resets: new levels for the envs whose episode ended, then every
        robot of `mask` moved onto its patch's start point (the pose's own offsets kept)."""
        # The env's rng is read when drawing: the env hands the task its own after building it.
        drawn = self.task.rng.uniform_(self._drawn)
        if self.cfg.curriculum:
            self._curriculum(mask, drawn[:, 0])
        else:
            torch.where(mask, self._pick(drawn[:, 0], self.rows), self.levels, out=self.levels)
            torch.where(mask, self._pick(drawn[:, 1], self.cols), self.types, out=self.types)
        origin = self.origins[self.levels, self.types]
        root = self.robot.root_pos
        torch.where(mask[:, None], root + origin, root, out=root)
        torch.where(mask[:, None], root[:, :2], self.start, out=self.start)
        self.walked.masked_fill_(mask, 0.0)
        self.started.logical_or_(mask)

    @staticmethod
    def _pick(drawn: torch.Tensor, count: int) -> torch.Tensor:
        """Uniform draws in [0, 1) as indices below `count`."""
        return (drawn * count).long().clamp_max(count - 1)

    def _curriculum(self, mask: torch.Tensor, drawn: torch.Tensor) -> None:
        """legged_gym's rule: up a level after walking more than half a patch, down after
        walking less than half the distance the command asked for; past the top level, a random
        one. New envs start on a random level up to `max_start_level`."""
        ended = mask & self.started
        up = self.walked > self.cfg.size / 2
        asked = (torch.linalg.vector_norm(self._command[:, :2], dim=1) * self.episode_s * 0.5
                 if self._command is not None else torch.zeros_like(self.walked))
        down = (self.walked < asked) & ~up
        moved = self.levels + up.long() - down.long()
        moved = torch.where(moved >= self.rows, self._pick(drawn, self.rows), moved.clamp_min(0))
        first = self._pick(drawn, min(self.cfg.max_start_level, self.rows - 1) + 1)
        torch.where(ended, moved, self.levels, out=self.levels)
        torch.where(mask & ~self.started, first, self.levels, out=self.levels)

    def metrics(self) -> dict[str, torch.Tensor]:
        """Each env's level, its row (0 for the easiest), as Isaac Lab's and mjlab's
        `terrain_levels`: as a mean over ended episodes, the curriculum's progress; and per
        type, the level of the envs of that type (NaN for the others), whose mean is over the
        episodes of that type."""
        level = self.levels.to(self.walked.dtype)
        out = {"level": level}
        for name, columns in self._of_type.items():
            out[f"level/{name}"] = torch.where(columns[self.types], level, torch.nan)
        return out
