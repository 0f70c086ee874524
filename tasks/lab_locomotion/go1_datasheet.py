"""go1-rough's Unitree Go1 (go1-flat's is Menagerie's: go1.py), written from its numbers: link
masses, centers of mass and principal inertias from Unitree's published URDF (go1_description;
the calf's 0.196 kg split into calf and foot as there), joint ranges and motor limits from its
datasheet (23.7 N m hip and thigh, 35.55 N m knee), rotor inertia 1.11842e-4 kg m^2 reflected
through 6:1 and 9:1 gearboxes as armature, and stiff PD gains (kp 35 N m/rad, kd 0.5 N m s/rad:
an earlier mjlab Go1 config's). The standing pose is Isaac Lab's.
"""

from lab_locomotion.quadruped import Link, Motor, Quadruped

ROTOR_INERTIA = 1.11842e-4

ROBOT = Quadruped(
    name="go1",
    trunk=Link(mass=5.204, com=(0.0223, 0.002, -0.0005), inertia=(0.0168, 0.0630, 0.0717)),
    trunk_half_size=(0.19, 0.0935, 0.057),
    hip=Link(mass=0.68, com=(-0.0049, 0.0076, -0.0001), inertia=(0.00047, 0.00073, 0.0004)),
    thigh=Link(mass=1.009, com=(-0.0030, 0.0193, -0.0305), inertia=(0.00461, 0.00479, 0.00071)),
    calf=Link(mass=0.136, com=(0.0060, 0.0010, -0.1150), inertia=(0.0011, 0.0011, 0.00003)),
    foot_mass=0.06,
    hip_offset=(0.1881, 0.04675),
    thigh_offset=0.08,
    thigh_length=0.213,
    calf_length=0.213,
    foot_radius=0.023,
    hip_range=(-0.863, 0.863),
    thigh_range=(-0.686, 4.501),
    calf_range=(-2.818, -0.888),
    hip_motor=Motor(kp=35.0, kd=0.5, effort=23.7, armature=ROTOR_INERTIA * 6**2),
    thigh_motor=Motor(kp=35.0, kd=0.5, effort=23.7, armature=ROTOR_INERTIA * 6**2),
    calf_motor=Motor(kp=35.0, kd=0.5, effort=35.55, armature=ROTOR_INERTIA * 9**2),
    stand_hip=0.1,
    stand_thigh=(0.8, 1.0),
    stand_calf=-1.5,
)
