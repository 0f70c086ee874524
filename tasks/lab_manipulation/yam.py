"""i2rt YAM from MuJoCo Menagerie (`i2rt_yam`, entry `scene`: the 6-DoF arm with its parallel
gripper on a floor), with its motors described as mjlab's (`asset_zoo/robots/i2rt_yam`):
Damiao DM4340 motors at the shoulder and elbow and DM4310 at the wrist and gripper, PD gains
from each joint's effective inertia for a 2 Hz natural frequency (the gripper's 1 Hz) and
damping ratio 2, each joint's action scale a quarter of its effort limit over its stiffness.
The gripper's motor drives the left finger through a crank (its rotor's inertia, speed and
torque reflected to the slide joint at 71 mm per 2.7 rad); the right finger follows through the
model's equality. As mjlab's, only the gripper collides (its wrist link and finger pads, the
pads' six small spheres with torsional and rolling friction) and the joints have no dry
friction. As mjlab's, the links weigh on the servos: Menagerie's model makes them weightless
(gravcomp), which is taken off, so that the arm sags under its weight unless its policy holds
it up, and steps as mjlab's does under the same actions (`bench/replay_diff.py`). The gripper's
servo takes any target, as mjlab's: Menagerie's control range of 0-41 mm would let it squeeze
the 4 cm cube with 2.2 N at most, where mjlab's squeezes with up to its 38 N."""

import math

from labcli.envs.mdp.description import Actuators, Collisions, RobotDescription, Site
from labcli.envs.spec import Menagerie

MODEL = Menagerie("i2rt_yam", "scene")

# (effort N m, speed rad/s, reflected rotor inertia kg m^2), from i2rt's motor drivers.
DM4340 = (28.0, 10.0, 0.032)
DM4310 = (10.0, 30.0, 0.0018)
# Each joint's effective inertia (kg m^2; the gripper's kg), mjlab's: what the gains act on.
EFFECTIVE_INERTIA = {"joint1": 0.123153, "joint2": 0.277411, "joint3": 0.232763,
                     "joint4": 0.030154, "joint5": 0.009126, "joint6": 0.002868,
                     "left_finger": 2.781624}
ARM_HZ, GRIPPER_HZ, DAMPING_RATIO = 2.0, 1.0, 2.0
# The crank's mean transmission: 71 mm of finger travel over the motor's 2.7 rad.
CRANK = 0.071 / 2.7  # m/rad
# mjlab limits the gripper's force to a tenth of the motor's, for the simulation's stability
# and (it says) on hardware too.
GRIPPER_FORCE_SHARE = 0.1


def _servo(joint: str, effort: float, speed: float, armature: float, hz: float,
           clip_targets: bool = True) -> Actuators:
    inertia, omega = EFFECTIVE_INERTIA[joint], 2.0 * math.pi * hz
    return Actuators(joints=[joint], effort_limit=effort, velocity_limit=speed,
                     armature=armature, stiffness=inertia * omega**2,
                     damping=2.0 * DAMPING_RATIO * inertia * omega, frictionloss=0.0,
                     clip_targets=clip_targets)


def _through_crank(effort: float, speed: float, armature: float) -> tuple[float, ...]:
    """A motor's (effort, speed, armature) reflected to the finger's slide (N, m/s, kg), its
    force cut to mjlab's share."""
    return GRIPPER_FORCE_SHARE * effort / CRANK, speed * CRANK, armature / CRANK**2


ROBOT = RobotDescription(
    base="fixed",
    # With Menagerie's compensation three seeds learnt to carry the cube after 44 M steps, 52 M
    # and not within 50 M; without it after 44, 50 and 46 M (docs/benchmarks.md, yam-lift).
    gravity_compensation=False,
    actuators={
        **{j: _servo(j, *DM4340, ARM_HZ) for j in ("joint1", "joint2", "joint3")},
        **{j: _servo(j, *DM4310, ARM_HZ) for j in ("joint4", "joint5", "joint6")},
        "gripper": _servo("left_finger", *_through_crank(*DM4310), GRIPPER_HZ,
                          clip_targets=False),
    },
    # Menagerie's grasp_site lies 4.4 cm beside the finger pads (mjlab moved its own to 1.4 cm
    # from them): the hand's point is the middle of the pads, oriented as grasp_site.
    sites={"pinch": Site(body="link_6", pos=(0.0, -0.044, 0.1298),
                         quat=(0.7071068, 0.0, 0.0, -0.7071068))},
    collisions=[
        Collisions(bodies=["[lr]f_down"], types=["sphere"], condim=6,
                   friction=(1.0, 5e-3, 5e-4), solref=(0.01, 1.0), priority=1),
        Collisions(bodies=["link_6", "[lr]f_rot", "[lr]f_down"], condim=3,
                   friction=(0.6, 5e-3, 1e-4)),
    ],
    # mjlab's HOME_KEYFRAME: elbow up, the hand over the floor in front, the gripper half open.
    home={"joint2": 1.047, "joint3": 1.05, "joint4": -0.9, "left_finger": 0.0375 / 2,
          "right_finger": -0.0375 / 2},
)
BASE = "arm"  # the body bolted to the world
HAND = "pinch"
FINGERS = ["lf_down", "rf_down"]
