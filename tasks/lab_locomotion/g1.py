"""Unitree G1 (29 DoF) from MuJoCo Menagerie (`unitree_g1`, entry `scene_mjx`: simplified
collision geoms and 49 explicit contact pairs, for fast simulation), with its motors as mjlab
1.6.0 describes them (asset_zoo/robots/unitree_g1/g1_constants.py): four motor types, their
rotor inertias reflected through two-stage planetary gearboxes as armature, PD gains for a
10 Hz natural frequency and damping ratio 2, and action scales of a quarter of the effort
limit over the stiffness. The waist's pitch and roll and the ankles are driven by two 5020
motors through a linkage: mjlab takes twice one motor's numbers, and so does this file.
"""

from labcli.envs.mdp.description import Actuators, RobotDescription
from labcli.envs.spec import Menagerie

MODEL = Menagerie("unitree_g1", "scene_mjx")


def reflected_inertia(rotor: tuple[float, float, float], gears: tuple[float, float, float]
                      ) -> float:
    """A two-stage planetary gearbox's inertia at its output (kg m^2): each stage's rotor
    inertia times the square of the ratio between it and the output."""
    return rotor[0] * (gears[1] * gears[2]) ** 2 + rotor[1] * gears[2] ** 2 + rotor[2]


ARMATURE_5020 = reflected_inertia((0.139e-4, 0.017e-4, 0.169e-4), (1, 1 + 46 / 18, 1 + 56 / 16))
ARMATURE_7520_14 = reflected_inertia((0.489e-4, 0.098e-4, 0.533e-4), (1, 4.5, 1 + 48 / 22))
ARMATURE_7520_22 = reflected_inertia((0.489e-4, 0.109e-4, 0.738e-4), (1, 4.5, 5))
ARMATURE_4010 = reflected_inertia((0.068e-4, 0.0, 0.0), (1, 5, 5))

ROBOT = RobotDescription(
    natural_frequency_hz=10.0,
    damping_ratio=2.0,
    actuators={
        "5020": Actuators(joints=[".*_elbow_joint", ".*_shoulder_pitch_joint",
                                  ".*_shoulder_roll_joint", ".*_shoulder_yaw_joint",
                                  ".*_wrist_roll_joint"],
                          effort_limit=25.0, velocity_limit=37.0, armature=ARMATURE_5020),
        "7520-14": Actuators(joints=[".*_hip_pitch_joint", ".*_hip_yaw_joint", "waist_yaw_joint"],
                             effort_limit=88.0, velocity_limit=32.0, armature=ARMATURE_7520_14),
        "7520-22": Actuators(joints=[".*_hip_roll_joint", ".*_knee_joint"],
                             effort_limit=139.0, velocity_limit=20.0, armature=ARMATURE_7520_22),
        "4010": Actuators(joints=[".*_wrist_pitch_joint", ".*_wrist_yaw_joint"],
                          effort_limit=5.0, velocity_limit=22.0, armature=ARMATURE_4010),
        "waist": Actuators(joints=["waist_pitch_joint", "waist_roll_joint"],
                           effort_limit=50.0, velocity_limit=37.0, armature=2 * ARMATURE_5020),
        "ankle": Actuators(joints=[".*_ankle_pitch_joint", ".*_ankle_roll_joint"],
                           effort_limit=50.0, velocity_limit=37.0, armature=2 * ARMATURE_5020),
    },
    feet=["left_foot", "right_foot"],
    foot_bodies=["left_ankle_roll_link", "right_ankle_roll_link"],
    mirror={"^left_": "right_", "^right_": "left_"},
    # Every joint's axis is along the base's x, y or z at the default pose, the same on both
    # sides: those about x and z (the waist's too) change sign in the mirror image.
    mirror_negated=[".*_roll_joint", ".*_yaw_joint"],
)
