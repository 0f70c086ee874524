"""A four-legged robot's MJCF from its numbers: a trunk and four legs of hip (abduction, x
axis), thigh and calf (pitch, y axis) joints driven by PD position actuators, a spherical foot
at the end of each calf, primitive collision geometry, on a flat plane. A robot is one
`Quadruped` (e.g. go1_datasheet.py); its MJCF is written next to it, named after the robot, and
checked against it by the tests:

    python -m lab_locomotion.quadruped go1_datasheet
"""

from __future__ import annotations

import importlib
import sys
from dataclasses import dataclass
from pathlib import Path

import mujoco

Vec3 = tuple[float, float, float]
LEGS = ("FL", "FR", "RL", "RR")  # front/rear, left/right: Unitree's names


@dataclass(frozen=True)
class Link:
    """A rigid link: its mass (kg), center of mass (m) and principal inertia (kg m^2) in its
    body's frame, written for the front-right leg; other legs are mirrored."""

    mass: float
    com: Vec3
    inertia: Vec3


@dataclass(frozen=True)
class Motor:
    """A joint's PD position servo: stiffness (N m/rad), damping (N m s/rad), effort limit
    (N m) and the rotor's reflected inertia (kg m^2, MuJoCo's armature)."""

    kp: float
    kd: float
    effort: float
    armature: float


@dataclass(frozen=True)
class Quadruped:
    name: str
    trunk: Link
    trunk_half_size: Vec3  # a box, m
    hip: Link
    thigh: Link
    calf: Link
    foot_mass: float
    hip_offset: tuple[float, float]  # |x|, |y| of the hip joints from the trunk's origin
    thigh_offset: float  # |y| of the thigh joint from the hip's
    thigh_length: float
    calf_length: float
    foot_radius: float
    hip_range: tuple[float, float]  # rad, for the left legs (mirrored for the right)
    thigh_range: tuple[float, float]
    calf_range: tuple[float, float]
    hip_motor: Motor
    thigh_motor: Motor
    calf_motor: Motor
    # The standing pose: hip angle of the left legs (the right ones mirrored), thigh angles of
    # the front and rear legs, calf angle.
    stand_hip: float
    stand_thigh: tuple[float, float]
    stand_calf: float
    timestep: float = 0.005
    foot_friction: float = 1.0


def _v(values) -> str:
    return " ".join(f"{v:.6g}" for v in values)


def _mirror(link: Link, sx: int, sy: int) -> str:
    x, y, z = link.com
    return (f'<inertial pos="{_v((x * sx, y * sy, z))}" mass="{link.mass:.6g}" '
            f'diaginertia="{_v(link.inertia)}"/>')


def _leg(q: Quadruped, leg: str) -> str:
    sx = 1 if leg[0] == "F" else -1
    sy = 1 if leg[1] == "L" else -1
    hx, hy = q.hip_offset
    lo, hi = q.hip_range
    hip_range = (lo, hi) if sy > 0 else (-hi, -lo)
    return f"""
      <body name="{leg}_hip" pos="{_v((hx * sx, hy * sy, 0))}">
        {_mirror(q.hip, sx, -sy)}
        <joint name="{leg}_hip_joint" class="hip" range="{_v(hip_range)}"/>
        <geom class="visual" type="cylinder" size="0.046 0.02" pos="{_v((0, 0.045 * sy, 0))}"
              zaxis="0 1 0"/>
        <body name="{leg}_thigh" pos="{_v((0, q.thigh_offset * sy, 0))}">
          {_mirror(q.thigh, 1, -sy)}
          <joint name="{leg}_thigh_joint" class="thigh" range="{_v(q.thigh_range)}"/>
          <geom name="{leg}_thigh" class="limb" size="0.02"
                fromto="0 0 0 0 0 {-q.thigh_length * 0.9:.6g}"/>
          <body name="{leg}_calf" pos="0 0 {-q.thigh_length:.6g}">
            {_mirror(q.calf, 1, 1)}
            <joint name="{leg}_calf_joint" class="calf" range="{_v(q.calf_range)}"/>
            <geom name="{leg}_calf" class="limb" size="0.012"
                  fromto="0 0 0 0 0 {-q.calf_length * 0.85:.6g}"/>
            <body name="{leg}_foot" pos="0 0 {-q.calf_length:.6g}">
              <inertial pos="0 0 0" mass="{q.foot_mass:.6g}" diaginertia="1e-5 1e-5 1e-5"/>
              <geom name="{leg}_foot" class="foot" size="{q.foot_radius:.6g}"/>
            </body>
          </body>
        </body>
      </body>"""


def _motor(name: str, axis: str, m: Motor) -> str:
    return (f'<default class="{name}"><joint axis="{axis}" '
            f'armature="{m.armature:.6g}"/><position kp="{m.kp:.6g}" kv="{m.kd:.6g}" '
            f'forcerange="{_v((-m.effort, m.effort))}"/></default>')


def mjcf(q: Quadruped, standing_height: float = 0.0, module: str = "") -> str:
    """The robot's MJCF. `standing_height`: the trunk's height in the "home" keyframe; `module`:
    lab_locomotion's module that holds `q`, named in the file's header."""
    legs = "".join(_leg(q, leg) for leg in LEGS)
    actuators = "\n    ".join(f'<position name="{leg}_{part}" class="{part}" '
                               f'joint="{leg}_{part}_joint"/>'
                               for leg in LEGS for part in ("hip", "thigh", "calf"))
    home = []
    for leg in LEGS:
        front, left = leg[0] == "F", leg[1] == "L"
        home += [q.stand_hip if left else -q.stand_hip,
                 q.stand_thigh[0] if front else q.stand_thigh[1], q.stand_calf]
    return f"""<!-- {q.name}: written by `python -m lab_locomotion.quadruped {module}` from
     {module}.py; edit that file, not this one. -->
<mujoco model="{q.name}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{q.timestep:.6g}" iterations="10" ls_iterations="20"/>
  <visual><global offwidth="1280" offheight="720"/></visual>
  <default>
    {_motor("hip", "1 0 0", q.hip_motor)}
    {_motor("thigh", "0 1 0", q.thigh_motor)}
    {_motor("calf", "0 1 0", q.calf_motor)}
    <!-- The robot's geoms touch the floor, not each other. -->
    <default class="limb"><geom type="capsule" contype="1" conaffinity="0"
      rgba="0.25 0.25 0.28 1"/></default>
    <default class="foot"><geom type="sphere" contype="1" conaffinity="0"
      friction="{q.foot_friction:.6g}" rgba="0.1 0.1 0.1 1"/></default>
    <default class="visual"><geom contype="0" conaffinity="0" rgba="0.3 0.3 0.33 1"/></default>
  </default>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.85 0.87 0.9" rgb2="0.7 0.73 0.78"
             width="512" height="512"/>
    <material name="grid" texture="grid" texrepeat="1 1" texuniform="true"/>
  </asset>
  <worldbody>
    <light pos="0 0 4" dir="0 0 -1" directional="true"/>
    <geom name="floor" type="plane" size="0 0 0.05" material="grid"/>
    <body name="trunk" pos="0 0 {standing_height:.6g}">
      <camera name="track" mode="trackcom" pos="0 -1.4 0.5" xyaxes="1 0 0 0 0.34 0.94"/>
      <freejoint name="root"/>
      {_mirror(q.trunk, 1, 1)}
      <geom name="trunk" type="box" size="{_v(q.trunk_half_size)}" contype="1" conaffinity="0"
            rgba="0.75 0.75 0.78 1"/>{legs}
    </body>
  </worldbody>
  <actuator>
    {actuators}
  </actuator>
  <keyframe>
    <key name="home" qpos="0 0 {standing_height:.6g} 1 0 0 0 {_v(home)}"
         ctrl="{_v(home)}"/>
  </keyframe>
</mujoco>
"""


def standing_height(q: Quadruped) -> float:
    """The trunk's height at which the feet, in the standing pose, just touch the floor."""
    model = mujoco.MjModel.from_xml_string(mjcf(q, 1.0))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_kinematics(model, data)
    lowest = min(data.xpos[model.body(f"{leg}_foot").id][2] for leg in LEGS)
    return round(1.0 - (lowest - q.foot_radius), 4)


def write(q: Quadruped, path: Path, module: str) -> None:
    path.write_text(mjcf(q, standing_height(q), module))


if __name__ == "__main__":
    module = sys.argv[1] if len(sys.argv) > 1 else "go1_datasheet"
    robot = importlib.import_module(f"lab_locomotion.{module}").ROBOT
    write(robot, Path(__file__).with_name(f"{robot.name}.xml"), module)
