"""Franka Emika Panda from MuJoCo Menagerie (`franka_emika_panda`, entry `mjx_scene`: the arm
with its hand on a floor, simplified collision geoms), bolted to the world at `link0`. Its
servos keep Menagerie's gains (kp 1000 / 750 / 300 and kv 20 / 4 / 2 by joint pair) and its
joints Franka's torque and speed limits; the default pose is Isaac Lab's (FRANKA_PANDA_CFG's
init_state), the hand open. The arm's own weight is compensated, as Franka's controller does
(Isaac Lab turns gravity off for its Panda); what it holds still weighs. The arm that picks
(`PICKING`) starts from the cube scene's own `home` keyframe instead: the hand pointing down
over the cube."""

from typing import Any

from labcli.envs.mdp.description import Actuators, RobotDescription
from labcli.envs.spec import Menagerie

MODEL = Menagerie("franka_emika_panda", "mjx_scene")
# The same scene with a cube on the floor in front of the arm.
CUBE_MODEL = Menagerie("franka_emika_panda", "mjx_single_cube")
ARMATURE = 0.1  # Menagerie's, for every arm joint
# Isaac Lab's action scale: 0.5 rad per unit of action, from the default pose.
ARM_SCALE = 0.5

ROBOT = RobotDescription(
    base="fixed",
    gravity_compensation=True,
    actuators={
        "shoulder": Actuators(joints=["joint[12]"], effort_limit=87.0, velocity_limit=2.175,
                              armature=ARMATURE, stiffness=1000.0, damping=20.0,
                              action_scale=ARM_SCALE),
        "elbow": Actuators(joints=["joint[34]"], effort_limit=87.0, velocity_limit=2.175,
                           armature=ARMATURE, stiffness=750.0, damping=4.0,
                           action_scale=ARM_SCALE),
        "forearm": Actuators(joints=["joint[567]"], effort_limit=12.0, velocity_limit=2.61,
                             armature=ARMATURE, stiffness=300.0, damping=2.0,
                             action_scale=ARM_SCALE),
        # One servo drives both fingers (the second follows through an equality), 0 to 4 cm.
        "hand": Actuators(joints=["finger_joint1"], effort_limit=200.0, velocity_limit=0.2,
                          armature=0.0, stiffness=350.0, damping=10.0, action_scale=0.04),
    },
    home={"joint1": 0.0, "joint2": -0.569, "joint3": 0.0, "joint4": -2.810, "joint5": 0.0,
          "joint6": 3.037, "joint7": 0.741, "finger_joint.": 0.04},
)

# Menagerie's mjx_single_cube `home`: the hand 38 cm over the floor, pointing down. From Isaac
# Lab's pose, where the hand leans 45 degrees forward and must turn while it reaches, the same
# rewards taught no grasp in 840 iterations; from this one the arm grasped and lifted the cube
# within 400.
PICK_HOME: dict[str, Any] = {"joint1": 0.0, "joint2": 0.3, "joint3": 0.0, "joint4": -1.57079,
                             "joint5": 0.0, "joint6": 2.0, "joint7": -0.7853,
                             "finger_joint.": 0.04}
PICKING = ROBOT.model_copy(update={"home": PICK_HOME})
FINGERS = ["left_finger", "right_finger"]
