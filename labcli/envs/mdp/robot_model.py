"""A robot description (`labcli.envs.mdp.description`) written into the model's MjSpec before
it is compiled: each actuated joint's armature, effort limit and (where given) passive damping
and friction, its actuator a PD position servo with the description's gains (or, for a group
whose torques lab computes, a motor), and the contact pairs it keeps."""

from __future__ import annotations

import re

import mujoco

from labcli.envs.mdp.description import Collisions, RobotDescription
from labcli.errors import LabError
from labcli.mjtree import robot_free_joints


def apply(spec: mujoco.MjSpec, robot: RobotDescription) -> None:
    # As loaded: the edits below change no body, joint or keyframe that the checks and the
    # compensation and home pose read.
    model = spec.compile()
    _check_base(spec, model, robot)
    f, zeta = robot.natural_frequency_hz, robot.damping_ratio
    for actuator in spec.actuators:
        joint = spec.joint(actuator.target)
        if actuator.trntype != mujoco.mjtTrn.mjTRN_JOINT or joint is None:
            raise LabError(f"actuator '{actuator.name}' drives no joint",
                           "a robot description describes joints that actuators drive")
        found = robot.group_of(joint.name)
        if found is None:
            raise LabError(f"joint '{joint.name}' (actuator '{actuator.name}') matches no group "
                           "of env.robot.actuators",
                           f"add a pattern for it to one of {sorted(robot.actuators)}")
        group = found[1]
        kp, kd = group.gains(f, zeta)
        joint.armature = group.armature
        if group.viscous_damping is not None:
            # MuJoCo 4's damping is a polynomial in the joint's speed: linear, nothing else.
            joint.damping[:] = 0.0
            joint.damping[0] = group.viscous_damping
        if group.frictionloss is not None:
            joint.frictionloss = group.frictionloss
        # Both limits: the joint's caps whatever acts through the actuator, the actuator's what
        # the servo asks for.
        joint.actfrcrange = [-group.effort_limit, group.effort_limit]
        joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE
        if group.explicit:
            # lab computes the torque each physics step (labcli.envs.mdp.motors): the actuator
            # passes it on, as a motor of unit gear.
            actuator.set_to_motor()
            actuator.gear[:] = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]
            actuator.inheritrange = 0.0
            actuator.ctrlrange = [-group.effort_limit, group.effort_limit]
            actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        else:
            inherit = actuator.inheritrange  # the servo's targets: the joint's range, if so
            was_motor = actuator.biastype == mujoco.mjtBias.mjBIAS_NONE
            actuator.set_to_position(kp=kp, kv=kd)
            actuator.inheritrange = inherit if group.clip_targets else 0.0
            if not group.clip_targets:
                actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
            elif was_motor:
                # A motor's control range is in N m (Menagerie's Go2): a servo's targets are
                # angles, within the joint's range.
                actuator.ctrlrange = joint.range
                actuator.ctrllimited = joint.limited
        actuator.forcerange = [-group.effort_limit, group.effort_limit]
        actuator.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    if robot.contact_pairs is not None:
        for pair in list(spec.pairs):
            if not any(re.fullmatch(p, pair.name) for p in robot.contact_pairs):
                spec.delete(pair)
    for name, site in robot.sites.items():
        body = spec.body(site.body)
        if body is None:
            raise LabError(f"env.robot.sites' '{name}' is on body '{site.body}', which model "
                           f"'{spec.modelname}' does not have",
                           f"name one of {', '.join(b.name for b in spec.bodies if b.name)}")
        body.add_site(name=name, pos=list(site.pos), quat=list(site.quat))
    if robot.collisions is not None:
        _set_collisions(spec, model, robot.collisions)
    if robot.gravity_compensation is not None:
        _compensate_gravity(spec, model, robot.gravity_compensation)
    if robot.home is not None:
        _write_home(spec, model, robot.home)


def _robot_bodies(model: mujoco.MjModel) -> list[int]:
    """The robot's bodies: the trees from the world's children that hold actuated joints (not
    the floor, nor an object it handles)."""
    roots = {int(model.body_rootid[model.jnt_bodyid[model.actuator_trnid[a, 0]]])
             for a in range(model.nu)}
    return [b for b in range(1, model.nbody) if int(model.body_rootid[b]) in roots]


def _compensate_gravity(spec: mujoco.MjSpec, model: mujoco.MjModel, weightless: bool) -> None:
    """Every body of the robot weightless on its joints, or every one weighing."""
    bodies = spec.bodies  # the compiled model's order: the world first, then depth first
    for body in _robot_bodies(model):
        bodies[body].gravcomp = 1.0 if weightless else 0.0


def _set_collisions(spec: mujoco.MjSpec, model: mujoco.MjModel,
                    entries: list[Collisions]) -> None:
    """Each collision geom of the robot set by the first entry matching its body and type; a
    geom no entry matches stops colliding. Visual geoms (no contype, no conaffinity) stay."""
    matched = [False] * len(entries)
    robot = set(_robot_bodies(model))
    geoms = spec.geoms  # the compiled model's order, as bodies
    for g in range(model.ngeom):
        body = int(model.geom_bodyid[g])
        if body not in robot or not (model.geom_contype[g] or model.geom_conaffinity[g]):
            continue
        body_name = model.body(body).name
        kind = mujoco.mjtGeom(int(model.geom_type[g])).name.removeprefix("mjGEOM_").lower()
        entry = next((i for i, e in enumerate(entries)
                      if any(re.fullmatch(p, body_name) for p in e.bodies)
                      and (e.types is None or kind in e.types)), None)
        geom = geoms[g]
        if entry is None or not entries[entry].collide:
            geom.contype = geom.conaffinity = 0
        else:
            e = entries[entry]
            geom.contype = geom.conaffinity = 1
            if e.condim is not None:
                geom.condim = e.condim
            if e.friction is not None:
                geom.friction = list(e.friction)
            if e.solref is not None:
                geom.solref = list(e.solref)
            if e.priority is not None:
                geom.priority = e.priority
        if entry is not None:
            matched[entry] = True
    for entry, used in zip(entries, matched, strict=True):
        if not used:
            raise LabError(f"env.robot.collisions' entry for bodies {entry.bodies}"
                           + (f" and types {entry.types}" if entry.types else "")
                           + " matches no collision geom of the robot",
                           "name bodies of the robot that have collision geoms")


HOME = "home"


def _write_home(spec: mujoco.MjSpec, model: mujoco.MjModel, home: dict[str, float]) -> None:
    """The keyframe `home`: qpos0 with the joints `home` names at its positions (a model's own
    `home` replaced)."""
    qpos = model.qpos0.copy()
    joints = [model.joint(j) for j in range(model.njnt)]
    for pattern, value in home.items():
        matched = [j for j in joints if re.fullmatch(pattern, j.name)]
        if not matched:
            raise LabError(f"env.robot.home's '{pattern}' matches no joint of model "
                           f"'{spec.modelname}'",
                           f"name one of {', '.join(j.name for j in joints if j.name)}")
        for joint in matched:
            if int(model.jnt_type[joint.id]) not in (int(mujoco.mjtJoint.mjJNT_HINGE),
                                                     int(mujoco.mjtJoint.mjJNT_SLIDE)):
                raise LabError(f"env.robot.home's '{pattern}' matches joint '{joint.name}', "
                               "which is not a hinge or slide", "name hinge or slide joints")
            qpos[model.jnt_qposadr[joint.id]] = value
    for key in list(spec.keys):
        if key.name == HOME:
            spec.delete(key)
    spec.add_key(name=HOME, qpos=qpos.tolist())


def _check_base(spec: mujoco.MjSpec, model: mujoco.MjModel, robot: RobotDescription) -> None:
    free = [model.joint(j).name or "(unnamed)" for j in robot_free_joints(model)]
    if (robot.base == "floating") == bool(free):
        return
    model = spec.modelname or "(unnamed)"
    if free:
        raise LabError(f"env.robot.base is '{robot.base}', but model '{model}' has a free joint "
                       f"('{free[0]}'): its base floats",
                       "set env.robot.base=floating, or describe a model bolted to the world")
    raise LabError(f"env.robot.base is 'floating', but model '{model}' has no free joint",
                   "set env.robot.base=fixed (bolted to the world) or planar (slide and hinge "
                   "joints in a plane)")


def action_scales(robot: RobotDescription, joints: list[str]) -> list[float]:
    """Each joint's action scale (rad per unit of action), from its group."""
    scales = []
    for joint in joints:
        found = robot.group_of(joint)
        if found is None:
            raise LabError(f"joint '{joint}' matches no group of env.robot.actuators",
                           f"add a pattern for it to one of {sorted(robot.actuators)}")
        scales.append(found[1].scale(robot.natural_frequency_hz, robot.damping_ratio))
    return scales
