"""Unitree Go2 from MuJoCo Menagerie (`unitree_go2`, entry `scene`), with its motors as Isaac
Lab's Go2 describes them (isaaclab_assets/robots/unitree.py, UNITREE_GO2_CFG): PD gains of
25 N m/rad and 0.5 N m s/rad, no joint friction and a speed limit of 30 rad/s; the torque
limits of Menagerie's motors (23.7 N m at hip and thigh, 45.43 N m at the knee) and the armature
Menagerie gives every joint. Menagerie's Go2 drives its joints with
torque motors: here they become position servos, targets within the joints' ranges. The
standing pose is Menagerie's `home` keyframe.
"""

from lab_locomotion.go1 import QUADRUPED_MIRROR
from labcli.envs.mdp.description import Actuators, RobotDescription
from labcli.envs.spec import Menagerie

MODEL = Menagerie("unitree_go2", "scene")

ROBOT = RobotDescription(
    actuators={
        "hip": Actuators(joints=[".*_hip_joint", ".*_thigh_joint"], effort_limit=23.7,
                         velocity_limit=30.0, armature=0.01, stiffness=25.0, damping=0.5,
                         viscous_damping=0.0, frictionloss=0.0),
        "knee": Actuators(joints=[".*_calf_joint"], effort_limit=45.43, velocity_limit=30.0,
                          armature=0.01, stiffness=25.0, damping=0.5, viscous_damping=0.0,
                          frictionloss=0.0),
    },
    foot_bodies=[".*_calf"],
    mirror=QUADRUPED_MIRROR,
    mirror_negated=[".*_hip_joint"],  # abduction, about the base's x axis
)
