"""A robot description (env.robot) written into a Menagerie model: gains from armature, limits,
action scales and contact pairs, checked against hand-computed values and Menagerie's own."""

from __future__ import annotations

import math

import mujoco
import pytest
from conftest import needs_menagerie
from lab_locomotion import g1, go1, go2
from lab_locomotion.config import G1FlatConfig
from pydantic import ValidationError

from labcli.envs import models
from labcli.envs.mdp import robot_model
from labcli.envs.mdp.description import Actuators, RobotDescription
from labcli.errors import LabError

pytestmark = needs_menagerie("unitree_g1")


def g1_spec() -> mujoco.MjSpec:
    return models.load_spec(g1.MODEL)


def test_g1_armatures_are_menageries_rotor_inertias_through_the_gearboxes():
    # Menagerie's g1_mjx.xml gives each joint class its armature; the file derives them from
    # Unitree's rotor inertias and gear ratios, as mjlab does.
    model = g1_spec().compile()
    for joint, armature in [("left_hip_pitch_joint", g1.ARMATURE_7520_14),
                            ("left_knee_joint", g1.ARMATURE_7520_22),
                            ("left_elbow_joint", g1.ARMATURE_5020),
                            ("left_ankle_pitch_joint", 2 * g1.ARMATURE_5020)]:
        assert armature == pytest.approx(model.dof_armature[model.joint(joint).dofadr[0]],
                                         rel=2e-3), joint


def test_the_description_sets_gains_limits_and_armature_of_each_actuator():
    spec = g1_spec()
    robot_model.apply(spec, g1.ROBOT)
    model = spec.compile()
    omega = 2 * math.pi * 10.0
    knee = model.actuator("left_knee_joint")
    kp, kd = g1.ARMATURE_7520_22 * omega**2, 2 * 2.0 * g1.ARMATURE_7520_22 * omega
    assert knee.gainprm[0] == pytest.approx(kp)
    assert knee.biasprm[:3] == pytest.approx([0.0, -kp, -kd])
    assert knee.forcerange == pytest.approx([-139.0, 139.0])
    joint = model.joint("left_knee_joint")
    assert model.dof_armature[joint.dofadr[0]] == pytest.approx(g1.ARMATURE_7520_22)
    assert model.jnt_actfrcrange[joint.id] == pytest.approx([-139.0, 139.0])
    # The servo's targets stay within the joint's range (Menagerie's inheritrange).
    assert knee.ctrlrange == pytest.approx(joint.range)
    wrist = model.actuator("right_wrist_yaw_joint")
    assert wrist.gainprm[0] == pytest.approx(g1.ARMATURE_4010 * omega**2)
    scales = robot_model.action_scales(g1.ROBOT, ["left_knee_joint", "waist_roll_joint"])
    assert scales == pytest.approx([0.25 * 139.0 / kp,
                                    0.25 * 50.0 / (2 * g1.ARMATURE_5020 * omega**2)])


def test_given_gains_and_scale_win_over_derived_ones():
    robot = g1.ROBOT.model_copy(deep=True)
    robot.actuators["7520-22"].stiffness = 200.0
    robot.actuators["7520-22"].damping = 5.0
    robot.actuators["7520-22"].action_scale = 0.1
    spec = g1_spec()
    robot_model.apply(spec, robot)
    knee = spec.compile().actuator("right_knee_joint")
    assert knee.gainprm[0] == 200.0 and knee.biasprm[:3] == pytest.approx([0, -200.0, -5.0])
    assert robot_model.action_scales(robot, ["right_knee_joint"]) == [0.1]


def test_the_task_config_takes_the_description_from_set():
    cfg = G1FlatConfig.model_validate(
        {"robot": {**g1.ROBOT.model_dump(), "natural_frequency_hz": 5.0}})
    assert cfg.robot.actuators["5020"].gains(5.0, 2.0)[0] == pytest.approx(
        g1.ARMATURE_5020 * (2 * math.pi * 5.0) ** 2)
    with pytest.raises(ValidationError, match="effort_limit"):
        G1FlatConfig.model_validate({"robot": {"actuators": {"a": {"joints": [".*"],
                                                                   "armature": 0.1}}}})


@needs_menagerie("unitree_go1")
def test_the_joints_own_damping_and_friction_are_the_description_s_where_it_gives_them():
    """Menagerie's Go1 gives every joint damping 2 (the hips' abduction 1) and frictionloss
    0.2; go1-flat's description takes them out, as mjlab's copy of the model does. Left out
    (None), they stay the model's."""
    legs = slice(6, 18)
    model = models.load_spec(go1.MODEL).compile()
    assert sorted(set(model.dof_damping[legs])) == [1.0, 2.0]
    assert set(model.dof_frictionloss[legs]) == {0.2}
    spec = models.load_spec(go1.MODEL)
    robot_model.apply(spec, go1.ROBOT)
    model = spec.compile()
    assert not model.dof_damping[legs].any() and not model.dof_frictionloss[legs].any()
    kept = go1.ROBOT.model_copy(deep=True)
    kept.actuators["knee"].viscous_damping = kept.actuators["knee"].frictionloss = None
    spec = models.load_spec(go1.MODEL)
    robot_model.apply(spec, kept)
    model = spec.compile()
    knee = model.joint("FR_calf_joint").dofadr[0]
    assert (model.dof_damping[knee], model.dof_frictionloss[knee]) == (2.0, 0.2)
    assert model.dof_damping[model.joint("FR_thigh_joint").dofadr[0]] == 0.0


@needs_menagerie("unitree_go2")
def test_a_torque_motor_becomes_a_servo_aiming_within_its_joint_s_range():
    """Menagerie's Go2 drives its joints with torque motors (control ±23.7 N m): as servos
    their targets are angles, so their control range becomes the joint's."""
    before = models.load_spec(go2.MODEL).compile()
    assert before.actuator("FR_hip").ctrlrange == pytest.approx([-23.7, 23.7])
    spec = models.load_spec(go2.MODEL)
    robot_model.apply(spec, go2.ROBOT)
    model = spec.compile()
    for name, joint in (("FR_hip", "FR_hip_joint"), ("RL_calf", "RL_calf_joint")):
        actuator = model.actuator(name)
        assert actuator.gainprm[0] == 25.0
        assert actuator.biasprm[:3] == pytest.approx([0.0, -25.0, -0.5])
        assert actuator.ctrlrange == pytest.approx(model.joint(joint).range)
    assert model.actuator("RL_calf").forcerange == pytest.approx([-45.43, 45.43])


def test_a_joint_no_group_matches_is_one_line():
    robot = RobotDescription(actuators={"legs": Actuators(joints=[".*_hip_.*", ".*_knee_joint"],
                                                          effort_limit=50.0, armature=0.01)})
    with pytest.raises(LabError) as err:
        robot_model.apply(g1_spec(), robot)
    assert err.value.message == ("joint 'left_ankle_pitch_joint' (actuator "
                                 "'left_ankle_pitch_joint') matches no group of "
                                 "env.robot.actuators")
    assert err.value.hint == "add a pattern for it to one of ['legs']"


def test_a_stiffness_of_zero_without_an_action_scale_is_refused():
    with pytest.raises(ValidationError, match="infinite"):
        RobotDescription(actuators={"all": Actuators(joints=[".*"], effort_limit=5.0,
                                                     armature=0.0)})


def test_contact_pairs_keeps_the_named_pairs_only():
    robot = g1.ROBOT.model_copy(update={"contact_pairs": [".*_foot[0-9]_floor"]})
    spec = g1_spec()
    robot_model.apply(spec, robot)
    model = spec.compile()
    assert model.npair == 6
    assert {model.pair(i).name for i in range(model.npair)} == {
        f"{side}_foot{i}_floor" for side in ("left", "right") for i in (1, 2, 3)}
