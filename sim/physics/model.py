"""A self-contained MJCF quadrotor: presets from public numbers, rotors as site actuators.

No mesh files and no downloads (docs/physics.md: the menagerie wheel fetches models at
first use and fails offline). Only numbers are taken from the public models:

- `crazyflie()`: Bitcraze Crazyflie 2 (mass, inertia, arm, kf/km, thrust-to-weight).
- `x2()`: Skydio X2 (mass, inertia, 0-13 N motors, yaw torque 0.0201 x thrust); bigger,
  so it is the one the pictures use (a Crazyflie is a few pixels wide at 10 m).

Each rotor is a `<general>` actuator on a site at the rotor with gear `0 0 1 0 0 +-kappa`:
one control (thrust in newtons) gives the thrust along the body z axis and the rotor's
reaction torque about it; roll and pitch torques come from the site's lever arm. Motor
lag is first order (`dyntype="filterexact"`, time constant tau).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

GRAVITY = 9.81
PHYSICS_DT = 0.002
"""Physics step (500 Hz); the controller runs every 5th step (100 Hz)."""

Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class Preset:
    """Physical numbers of one craft (SI units)."""

    name: str
    mass: float
    """kg"""
    inertia: Vec3
    """Diagonal inertia about the centre of mass, kg m^2."""
    rotors: tuple[tuple[float, float], ...]
    """Rotor (x, y) positions in the body frame, m; x forward, y left."""
    spins: tuple[int, ...]
    """Reaction-torque sign of each rotor about body z (+1 or -1)."""
    kappa: float
    """Yaw torque per newton of thrust, m (km / kf)."""
    max_thrust: float
    """Largest thrust of one motor, N."""
    tau: float
    """Motor time constant, s."""
    half_size: Vec3
    """Half extents of the body box (collision and picture), m."""
    rotor_radius: float
    """Propeller disc radius (picture only), m."""

    @property
    def hover_thrust(self) -> float:
        """Thrust of one motor in hover, N."""
        return self.mass * GRAVITY / len(self.rotors)

    @property
    def rest_height(self) -> float:
        """Height of the centre of mass of a craft standing on flat ground, m."""
        return self.half_size[2]


def crazyflie() -> Preset:
    """Crazyflie 2 class: 27 g, thrust-to-weight 2.25, 20 ms motor lag (docs/physics.md)."""
    a = 0.0397 / math.sqrt(2.0)  # arm 0.0397 m from the centre, rotors on the diagonals
    mass = 0.027
    return Preset(
        name="crazyflie",
        mass=mass,
        inertia=(2.3951e-5, 2.3951e-5, 3.2347e-5),
        rotors=((a, -a), (-a, -a), (-a, a), (a, a)),
        spins=(-1, 1, -1, 1),
        kappa=7.94e-12 / 3.16e-10,  # km / kf = 0.0251
        max_thrust=2.25 * mass * GRAVITY / 4.0,
        tau=0.02,
        half_size=(0.035, 0.035, 0.01),
        rotor_radius=0.023,
    )


def x2() -> Preset:
    """Skydio X2 class: 1.325 kg, motors 0-13 N (hover 3.25 N), 40 ms motor lag."""
    return Preset(
        name="x2",
        mass=1.325,
        inertia=(0.0367, 0.0254, 0.0605),
        rotors=((0.14, -0.18), (-0.14, -0.18), (-0.14, 0.18), (0.14, 0.18)),
        spins=(-1, 1, -1, 1),
        kappa=0.0201,
        max_thrust=13.0,
        tau=0.04,
        half_size=(0.12, 0.09, 0.04),
        rotor_radius=0.09,
    )


PRESETS = {"crazyflie": crazyflie, "x2": x2}


def preset(name: str) -> Preset:
    """A preset by name; ValueError names the known ones."""
    try:
        return PRESETS[name]()
    except KeyError:
        known = ", ".join(PRESETS)
        raise ValueError(f"unknown quadrotor preset {name!r} (known: {known})") from None


def _f(v: float) -> str:
    return f"{v:.9g}"


def _v(*vs: float) -> str:
    return " ".join(_f(v) for v in vs)


def quad_body(
    p: Preset,
    name: str,
    pos: Vec3,
    *,
    free: bool,
    rgba: str = "0.2 0.6 0.2 1",
    scale: float = 1.0,
) -> str:
    """MJCF of one craft. `free` gives it a free joint and rotor sites (physics);
    otherwise it is a mocap body for replay (pictures), drawn `scale` times its size so
    it stays visible from a camera that sees the whole swarm."""
    if free and scale != 1.0:
        raise ValueError("only a picture (mocap) craft may be scaled")
    hx, hy, hz = (v * scale for v in p.half_size)
    rotors = [(x * scale, y * scale) for x, y in p.rotors]
    radius = p.rotor_radius * scale
    parts = [f'<body name="{name}" pos="{_v(*pos)}"' + (' mocap="true">' if not free else ">")]
    if free:
        parts.append(f'<freejoint name="{name}_free"/>')
        parts.append(
            f'<inertial pos="0 0 0" mass="{_f(p.mass)}" diaginertia="{_v(*p.inertia)}"/>'
        )
    # The box is the collision shape (ground contact = landed or crashed); arms and
    # propeller discs are pictures only (contype 0).
    parts.append(
        f'<geom name="{name}_hull" type="box" size="{_v(hx, hy, hz)}" rgba="{rgba}"'
        + ("" if free else ' contype="0" conaffinity="0"')
        + "/>"
    )
    for i, (x, y) in enumerate(rotors):
        parts += _rotor_parts(name, i, x, y, hz, radius, free=free)
    parts.append("</body>")
    return "\n".join(parts)


def _rotor_parts(name: str, i: int, x: float, y: float, hz: float, radius: float, *,
                 free: bool) -> list[str]:
    """Rotor `i` at (x, y): its arm and propeller disc, and with physics the site its
    thrust acts at."""
    parts = [
        f'<geom name="{name}_arm{i}" type="capsule" fromto="0 0 0 {_v(x, y, 0)}" '
        f'size="{_f(hz * 0.4)}" contype="0" conaffinity="0" rgba="0.25 0.25 0.25 1"/>',
        f'<geom name="{name}_prop{i}" type="cylinder" pos="{_v(x, y, hz)}" '
        f'size="{_v(radius, hz * 0.15)}" contype="0" conaffinity="0" '
        f'rgba="0.1 0.1 0.1 0.5"/>',
    ]
    if free:
        parts.append(f'<site name="{name}_rotor{i}" pos="{_v(x, y, hz)}"/>')
    return parts


def rotor_actuators(p: Preset, name: str) -> str:
    """The four rotor actuators: thrust plus reaction torque, first-order motor lag."""
    out = []
    for i, s in enumerate(p.spins):
        out.append(
            f'<general name="{name}_motor{i}" site="{name}_rotor{i}" '
            f'gear="0 0 1 0 0 {_f(s * p.kappa)}" ctrllimited="true" '
            f'ctrlrange="0 {_f(p.max_thrust)}" dyntype="filterexact" dynprm="{_f(p.tau)}" '
            f'gaintype="fixed" gainprm="1" biastype="none"/>'
        )
    return "\n".join(out)


_HEADER = f"""<option timestep="{PHYSICS_DT}" gravity="0 0 -{GRAVITY}"/>
<visual>
  <global offwidth="640" offheight="480"/>
  <quality shadowsize="0" offsamples="0"/>
</visual>
<asset>
  <texture name="grid" type="2d" builtin="checker" rgb1="0.82 0.84 0.86"
    rgb2="0.74 0.76 0.78" width="256" height="256"/>
  <material name="grid" texture="grid" texrepeat="20 20" reflectance="0"/>
</asset>"""


def quad_xml(p: Preset, home: Vec3 = (0.0, 0.0, 0.0), name: str = "quad") -> str:
    """A single craft standing on the ground at `home` (x, y, ground z): one robot
    process steps exactly this model."""
    start = (home[0], home[1], home[2] + p.rest_height)
    return f"""<mujoco model="{name}">
{_HEADER}
<worldbody>
  <geom name="floor" type="plane" size="0 0 0.1" pos="0 0 {_f(home[2])}" material="grid"/>
  {quad_body(p, name, start, free=True)}
</worldbody>
<actuator>
  {rotor_actuators(p, name)}
</actuator>
</mujoco>"""


def scene_xml(p: Preset, n: int, extent: float = 20.0, scale: float = 2.0) -> str:
    """N mocap crafts (`quad1`..`quadN`, drawn `scale` times their size) over a floor,
    for replaying trajectories."""
    bodies = "\n".join(
        quad_body(p, f"quad{i + 1}", (2.0 * i, 0.0, p.rest_height), free=False, scale=scale)
        for i in range(n)
    )
    return f"""<mujoco model="swarm">
{_HEADER}
<visual><headlight ambient="0.45 0.45 0.45" diffuse="0.5 0.5 0.5" specular="0 0 0"/></visual>
<asset>
  <texture name="sky" type="skybox" builtin="gradient" rgb1="0.62 0.75 0.9" rgb2="1 1 1"
    width="256" height="256"/>
</asset>
<worldbody>
  <light pos="0 0 30" dir="0 0 -1" directional="true" castshadow="false"/>
  <geom name="floor" type="plane" size="{_f(extent)} {_f(extent)} 0.1" material="grid"/>
  {bodies}
</worldbody>
</mujoco>"""
