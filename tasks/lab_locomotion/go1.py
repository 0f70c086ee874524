"""Unitree Go1 from MuJoCo Menagerie (`unitree_go1`, entry `scene`), with its motors as mjlab
1.6.0 describes them (asset_zoo/robots/unitree_go1/go1_constants.py): one motor type, its rotor
inertia of 1.11842e-4 kg m^2 reflected through the hip's 6:1 and the knee's 9:1 gearbox as
armature, the datasheet's torque and speed limits (23.7 N m and 30.1 rad/s at hip and thigh,
35.55 N m and 20.06 rad/s at the knee), PD gains for a 10 Hz natural frequency and damping
ratio 2. Menagerie's joints add damping 2 and frictionloss 0.2 that mjlab's copy of the model
leaves out, and so does this file: the servo's damping is the joint's. The standing pose is
Menagerie's `home` keyframe.
"""

from labcli.envs.mdp.description import Actuators, RobotDescription
from labcli.envs.spec import Menagerie

MODEL = Menagerie("unitree_go1", "scene")
# Unitree's URDF (go1_description): Ixx of the motor's rotor, kg m^2. Not imported from
# go1_datasheet.py, whose MJCF writer imports MuJoCo: registering the tasks must not.
ROTOR_INERTIA = 1.11842e-4
# Unitree's quadrupeds: front and rear legs, right and left.
QUADRUPED_MIRROR = {"^FR_": "FL_", "^FL_": "FR_", "^RR_": "RL_", "^RL_": "RR_"}

ROBOT = RobotDescription(
    natural_frequency_hz=10.0,
    damping_ratio=2.0,
    actuators={
        "hip": Actuators(joints=[".*_hip_joint", ".*_thigh_joint"], effort_limit=23.7,
                         velocity_limit=30.1, armature=ROTOR_INERTIA * 6**2,
                         viscous_damping=0.0, frictionloss=0.0),
        "knee": Actuators(joints=[".*_calf_joint"], effort_limit=35.55, velocity_limit=20.06,
                          armature=ROTOR_INERTIA * 9**2, viscous_damping=0.0, frictionloss=0.0),
    },
    feet=["FR", "FL", "RR", "RL"],
    foot_bodies=[".*_calf"],
    mirror=QUADRUPED_MIRROR,
    mirror_negated=[".*_hip_joint"],  # abduction, about the base's x axis
)
