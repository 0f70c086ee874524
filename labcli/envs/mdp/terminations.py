"""Termination terms: each returns a boolean `[num_envs]`; those configured `time_out` end the
episode as a time-out (`RobotTask.time_outs`), the others as a failure."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import mujoco
import torch

from labcli.envs.mdp import config as c
from labcli.envs.mdp import sensors
from labcli.errors import LabError

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask


def root_height_below_minimum(task: RobotTask, cfg: c.BaseHeightBelow) -> torch.Tensor:
    return task.base_height() < cfg.minimum_height


def bad_orientation(task: RobotTask, cfg: c.BadOrientation) -> torch.Tensor:
    """Tilted past the limit: the angle between the root's z axis and the world's up is
    acos(-g_z) in the root's frame, compared as a cosine (no acos per step)."""
    return task.robot.up_z < math.cos(cfg.limit_angle)


class illegal_contact:  # noqa: N801 - a term, named as Isaac Lab's
    def __init__(self, task: RobotTask, cfg: c.IllegalContact):
        self.contacts = sensors.BodyContacts(task, cfg.bodies, cfg.threshold, cfg.against)

    @staticmethod
    def sensors(model: mujoco.MjModel, cfg: c.IllegalContact) -> list[sensors.Sensor]:
        return sensors.BodyContacts.sensors(model, cfg.bodies, cfg.against)

    def __call__(self) -> torch.Tensor:
        return self.contacts().any(dim=1)


class terrain_out_of_bounds:  # noqa: N801
    def __init__(self, task: RobotTask, cfg: c.TerrainOutOfBounds):
        if task.terrain is None:
            raise LabError("termination terrain_out_of_bounds reads the terrain, and the task "
                           "has none", "give env.terrain, or leave the term out (null)")
        grid = task.terrain
        self.limit = task.constant([count * grid.cfg.size / 2 + grid.cfg.border - cfg.margin
                                    for count in (grid.rows, grid.cols)])
        self.robot = task.robot

    def __call__(self) -> torch.Tensor:
        return (self.robot.root_xy.abs() > self.limit).any(dim=1)
