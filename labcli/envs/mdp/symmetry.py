"""A robot task's left-right mirror image, as index maps with signs over its observations and
actions: what symmetric data augmentation (RSL-RL's `symmetry_cfg`, Mittal et al., ICRA 2024)
needs. A legged robot mirrored through its base's x-z plane sees each observation column turned
into another (a left joint's into the right one's) with a sign; a policy that walks well acts
the mirror image of its action there.

The robot description declares which joint is which joint's image, and which change sign
(`RobotDescription.mirror`, `mirror_negated`); each observation term's config class says how
its columns change (`ObsTerm.mirror`). A term that says nothing, or a robot that declares no
mirror, is one line, not a guess."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import torch

from labcli.errors import LabError

# How a run turns symmetric training off (RSL-RL's keys), a config or --set having turned it on.
OFF = "--set agent.symmetry_augmentation=false --set agent.mirror_loss_coef=0"

if TYPE_CHECKING:
    from labcli.envs.mdp.description import RobotDescription
    from labcli.envs.mdp.task import Built, RobotTask

# The signs of a base-frame vector's x, y, z in the mirror image through the x-z plane: a
# velocity's or gravity's y flips; an angular velocity's x and z.
POLAR, AXIAL = (1.0, -1.0, 1.0), (-1.0, 1.0, -1.0)


@dataclass(frozen=True)
class Mirror:
    """`observations(obs)[:, i] = obs_sign[i] * obs[:, obs_index[i]]`, and likewise for the
    critic's own observations and the actions: each map is its own inverse."""

    obs_index: torch.Tensor
    obs_sign: torch.Tensor
    action_index: torch.Tensor
    action_sign: torch.Tensor
    critic_index: torch.Tensor
    critic_sign: torch.Tensor

    def observations(self, obs: torch.Tensor) -> torch.Tensor:
        return obs.index_select(-1, self.obs_index) * self.obs_sign

    def critic_observations(self, obs: torch.Tensor) -> torch.Tensor:
        return obs.index_select(-1, self.critic_index) * self.critic_sign

    def actions(self, actions: torch.Tensor) -> torch.Tensor:
        return actions.index_select(-1, self.action_index) * self.action_sign


def mirror_of(task: RobotTask) -> Mirror:
    """The mirror maps of `task`'s observations and actions, or a LabError saying what lacks
    one."""
    robot = task.cfg.robot
    if robot is None:
        raise LabError("symmetric training needs the robot's mirror image, and this task has no "
                       "robot description (env.robot) to declare one",
                       f"train it without symmetry ({OFF})")
    if not robot.mirror:
        raise LabError("symmetric training needs the robot's mirror image, and this task's robot "
                       "description declares none",
                       "set env.robot.mirror and env.robot.mirror_negated (docs/plugins.md), or "
                       f"train without symmetry ({OFF})")
    joints = task.robot.joint_names
    index, sign = [], []
    for joint in joints:
        image, flips = robot.mirrored(joint)
        if image not in joints:
            raise LabError(f"the mirror image of joint '{joint}' is '{image}', which the robot's "
                           "actuators do not drive",
                           "fix env.robot.mirror: each actuated joint's image is actuated too")
        index.append(joints.index(image))
        sign.append(flips)
    obs_index, obs_sign = _columns_map(task._obs, task._obs_names, (index, sign), robot,
                                       "observations")
    assert len(obs_index) == len(task.observation_names)
    # The critic's: the policy's columns, then its own terms' (critic_observations: privileged).
    extras = _columns_map(task._critic_extras, task._critic_extra_names, (index, sign), robot,
                          "critic_extras")
    critic_index = obs_index + [len(obs_index) + i for i in extras[0]]
    # The signs in the learner's float32, the observations' and actions' own dtype.
    device = task.ones.device
    return Mirror(torch.tensor(obs_index, device=device),
                  torch.tensor(obs_sign, dtype=torch.float32, device=device),
                  torch.tensor(index, device=device),
                  torch.tensor(sign, dtype=torch.float32, device=device),
                  torch.tensor(critic_index, device=device),
                  torch.tensor(obs_sign + extras[1], dtype=torch.float32, device=device))


def _columns_map(built: list[Built], names: list[list[str]], joints: tuple[list[int], list[float]],
                 robot: RobotDescription, group: str) -> tuple[list[int], list[float]]:
    """Where each column of a group's concatenated terms (each frame of a term, oldest first)
    comes from in the mirror image, and its sign there."""
    index: list[int] = []
    signs: list[float] = []
    for term, columns in zip(built, names, strict=True):
        local, term_signs = _term_map(term, columns, joints, robot, group)
        for _ in range(term.cfg.frames):
            index += [len(index) + i for i in local]
            signs += term_signs
    return index, signs


def mirror_of_env(env: Any) -> Mirror:
    """The mirror maps of a lab robot task's env (wrapped or not), or a LabError."""
    from labcli.envs.mdp.task import RobotTask

    task = getattr(env.unwrapped, "task", None)
    if not isinstance(task, RobotTask):
        raise LabError("symmetric training needs a robot task whose robot description "
                       "declares its mirror image", f"train this task without symmetry ({OFF})")
    return mirror_of(task)


def _term_map(built: Built, names: list[str], joints: tuple[list[int], list[float]],
              robot: RobotDescription, group: str) -> tuple[list[int], list[float]]:
    """Where each of a term's columns comes from in the mirror image, and its sign there
    (`joints`: that map over the actuated joints, which are the actions' too)."""
    kind = type(built.cfg).mirror
    width = len(names)
    identity = list(range(width))
    if kind == "even":
        return identity, [1.0] * width
    if kind in ("polar", "axial") and width == 3:
        return identity, list(POLAR if kind == "polar" else AXIAL)
    if kind == "joints" and width == len(joints[0]):
        return joints
    if kind == "scan":
        points = {_point(name): i for i, name in enumerate(names)}
        images = [points.get((x, 0.0 - y)) for x, y in points]
        if None not in images:
            return images, [1.0] * width
    if kind == "feet":  # a column per foot, named by its body
        images = [f"{built.name}.{robot.mirrored(foot)[0]}" for foot in built.made.names]
        if all(image in names for image in images):
            return [names.index(image) for image in images], [1.0] * width
    if kind == "command":
        signs = getattr(built.made.command, "mirror_signs", None)
        if signs is not None and len(signs) == width:
            return identity, list(signs)
    raise LabError(f"observation term '{built.name}' has no mirror image that lab knows "
                   f"({type(built.cfg).__name__})",
                   f"leave it out (--set env.{group}.{built.name}=null) or train without "
                   f"symmetry ({OFF})")


def _point(name: str) -> tuple[float, float]:
    """A height-scan column's point (`term.x,y`, as `height_scan` names them), rounded as
    named, with -0 as 0."""
    x, y = (round(float(v), 2) + 0.0 for v in name.split(".", 1)[1].split(","))
    return x, y
