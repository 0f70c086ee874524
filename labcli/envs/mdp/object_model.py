"""The objects of a task's config (`env.objects`: boxes with free joints) written into the
model's MjSpec before the robot description, so that the robot's home keyframe holds their
starting poses."""

from __future__ import annotations

import mujoco

from labcli.envs.mdp import config as c
from labcli.errors import LabError


def apply(spec: mujoco.MjSpec, objects: dict[str, c.Box]) -> None:
    for name, box in objects.items():
        if spec.body(name) is not None:
            raise LabError(f"env.objects names body '{name}', which model "
                           f"'{spec.modelname}' already has", "give the object another name")
        body = spec.worldbody.add_body(name=name, pos=list(box.pos))
        body.add_freejoint(name=f"{name}_joint")
        body.add_geom(name=f"{name}_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(box.size),
                      mass=box.mass, rgba=list(box.rgba))
