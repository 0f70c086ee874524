"""What the foot terms share (labcli/envs/mdp/rewards.py: `feet_clearance`, `feet_swing_height`,
`feet_slip`, `soft_landing`), made once per task through `RobotTask.shared` and computed once
per state: each foot's contact with the terrain, from a MuJoCo contact sensor on the foot's
subtree against the world body's geoms (mjlab's G1 `feet_ground_contact`), and its site's height
and velocity, from frame sensors. Lab sees the state once per env step, at its end; mjlab's
contact sensor tracks every physics step."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import mujoco
import torch

from labcli.envs.mdp import names, sensors
from labcli.errors import LabError
from labcli.mjtree import in_subtree

if TYPE_CHECKING:
    from labcli.envs.mdp.task import RobotTask

# The terrain: the world body's geoms (a flat floor, or a terrain's static geoms).
TERRAIN = ("world", "body")


def _contact(body: str) -> sensors.Sensor:
    return sensors.subtree_contact(body, *TERRAIN)


def _site_sensors(site: str) -> list[sensors.Sensor]:
    return [sensors.frame("framepos", "site", site), sensors.frame("framelinvel", "site", site)]


def site_names(model: mujoco.MjModel, patterns: Sequence[str]) -> list[str]:
    all_sites = names.all_names(model, "site")
    return [all_sites[i] for i in names.resolve(model, "site", patterns)]


def paired_sites(model: mujoco.MjModel, bodies: Sequence[str], patterns: Sequence[str]
                 ) -> list[str]:
    """The named sites in the order of `bodies`, one on each foot (in its subtree): the terms
    that read a foot's contact and its site's motion pair them so."""
    sites = site_names(model, patterns)
    ids = [names.resolve_one(model, "body", b) for b in bodies]
    paired = []
    for body, foot in zip(bodies, ids, strict=True):
        on_it = [s for s in sites if in_subtree(model, int(model.site(s).bodyid[0]), foot)]
        if len(on_it) != 1:
            raise LabError(f"foot '{body}' has {len(on_it)} of the sites {sites} on it "
                           f"({', '.join(on_it) or 'none'})",
                           "name one site on each foot, in env.rewards.<term>.sites")
        paired.append(on_it[0])
    stray = sorted(set(sites) - set(paired))
    if stray:
        raise LabError(f"site(s) {', '.join(stray)} are on none of the feet {list(bodies)}",
                       "name one site on each foot, in env.rewards.<term>.sites")
    return paired


class FootContacts:
    """Per foot (`[n, feet]`, the feet in model order): `touching()`, MuJoCo matched a contact
    of its subtree with the terrain (as mjlab's `found`, whatever the force); `force()`, their
    net force `[n, feet, 3]` (N, world frame); `first_contact()`, touching at this step's end and
    not at the last's (mjlab: landed within the env step's physics steps); `air_time()`, the
    time in the air up to this step's end (s; 0 while touching). After a reset no foot has
    touched yet: a foot on the ground makes its first contact in the episode's first step, as
    in mjlab, whose contact time restarts at 0."""

    carried = ("_air", "_was_touching")

    def __init__(self, task: RobotTask, bodies: list[str]):
        self.bodies, self.robot = bodies, task.robot
        n, k = task.num_envs, len(bodies)
        self._data = sensors.columns(task, [[_contact(b).name] for b in bodies])
        self._shape = (n, k, 4)  # found, then the force's x, y, z
        self._key = ("foot_contacts", tuple(bodies))
        self._dt = task.constant(task.step_dt)
        self._air = task.ones.new_zeros(n, k)
        self._was_touching = torch.zeros(n, k, dtype=torch.bool, device=task.ones.device)

    @staticmethod
    def sensors(model: mujoco.MjModel, patterns: Sequence[str]) -> list[sensors.Sensor]:
        return [_contact(b) for b in sensors.body_names(model, patterns)]

    @classmethod
    def of(cls, task: RobotTask, patterns: Sequence[str]) -> FootContacts:
        """The task's one state of these feet (patterns of body names)."""
        bodies = sensors.body_names(task.model, patterns)
        return task.shared(("foot_contacts", tuple(bodies)), lambda: cls(task, bodies))

    def _raw(self) -> torch.Tensor:
        return self.robot.per_state((*self._key, "raw"), lambda: self._data().view(self._shape))

    def touching(self) -> torch.Tensor:
        return self.robot.per_state((*self._key, "touching"), lambda: self._raw()[..., 0] > 0.0)

    def force(self) -> torch.Tensor:
        return self._raw()[..., 1:]

    def force_norm(self) -> torch.Tensor:
        return self.robot.per_state((*self._key, "force_norm"), lambda: (
            torch.linalg.vector_norm(self.force(), dim=2)))

    def first_contact(self) -> torch.Tensor:
        return self.robot.per_state((*self._key, "first_contact"), lambda: (
            self.touching() & ~self._was_touching))

    def air_time(self) -> torch.Tensor:
        return self.robot.per_state((*self._key, "air_time"), lambda: (
            (self._air + self._dt).masked_fill_(self.touching(), 0.0)))

    def air_time_kept(self) -> torch.Tensor:
        """`air_time()` as `after_step` kept it (0 after a reset): what an observation reads,
        the same whether or not other envs were reset since."""
        return self._air

    def after_step(self) -> None:
        self._air.copy_(self.air_time())
        self._was_touching.copy_(self.touching())

    def reset(self, mask: torch.Tensor) -> None:
        self._air.masked_fill_(mask[:, None], 0.0)
        self._was_touching.masked_fill_(mask[:, None], False)


class FootSites:
    """Per named site (`[n, sites]`, in the order given): `heights()` above the ground (m) and
    `speed_xy()`, the norm of its horizontal velocity (m/s, world frame), from framepos and
    framelinvel sensors."""

    def __init__(self, task: RobotTask, sites: list[str]):
        self.sites, self.robot = sites, task.robot
        n, k = task.num_envs, len(sites)
        self._pos = sensors.columns(task, [[_site_sensors(s)[0].name] for s in sites])
        self._vel = sensors.columns(task, [[_site_sensors(s)[1].name] for s in sites])
        self._shape = (n, k, 3)
        self._key = ("foot_sites", tuple(sites))
        self.terrain = task.terrain

    @staticmethod
    def sensors(model: mujoco.MjModel, sites: Sequence[str]) -> list[sensors.Sensor]:
        return [s for site in sites for s in _site_sensors(site)]

    @classmethod
    def of(cls, task: RobotTask, sites: Sequence[str]) -> FootSites:
        """The task's one view of these sites (names, in this order)."""
        return task.shared(("foot_sites", tuple(sites)), lambda: cls(task, list(sites)))

    def heights(self) -> torch.Tensor:
        """Above the terrain under each site where the task has terrain, else above z = 0."""
        def above() -> torch.Tensor:
            pos = self._pos().view(self._shape)
            if self.terrain is None:
                return pos[..., 2]
            return pos[..., 2] - self.terrain.heights(pos[..., :2])

        return self.robot.per_state((*self._key, "heights"), above)

    def speed_xy(self) -> torch.Tensor:
        return self.robot.per_state((*self._key, "speed_xy"), lambda: (
            torch.linalg.vector_norm(self._vel().view(self._shape)[..., :2], dim=2)))


def feet_sensors(model: mujoco.MjModel, bodies: Sequence[str], sites: Sequence[str]
                 ) -> list[sensors.Sensor]:
    """The sensors of the feet's contacts (`bodies`: patterns) and of one site on each."""
    found = sensors.body_names(model, bodies)
    return [*FootContacts.sensors(model, found),
            *FootSites.sensors(model, paired_sites(model, found, sites))]
