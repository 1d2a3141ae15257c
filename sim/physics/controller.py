"""Geometric SE(3) controller with motor mixing (Lee, Leok, McClamroch 2010), pure numpy.

Position loop: desired force F = -kx*sat(ex) - kv*ev - ki*integral + m*g*e3 + m*a_d.
The position error is saturated (1.5 m) so a long move cruises at a bounded speed
instead of tilting hard; the integral only runs near the target and is capped at 30% of
the weight, so it trims the steady state without winding up during moves
(docs/physics.md). The tilt of F is limited so the craft never trades all lift for speed.

Attitude loop: b3d = F/|F|, yaw sets b1; eR = vee(Rd'R - R'Rd)/2; M = -kR*eR - kW*eW
+ W x JW. Gains are set from bandwidths: kR = J*w^2, kW = 2*zeta*J*w per axis. An
attitude bandwidth of ~15 rad/s suits the X2's 40 ms motor lag (25 rad/s dipped 20-40 cm
in moves, docs/physics.md).

Mixing: [T, Mx, My, Mz] = A f with columns (1, y_i, -x_i, s_i*kappa) per rotor; f =
A^-1 [...], clipped to the motor range. Cross products are written out by hand
(np.cross on 3-vectors costs ~15 us, this ~2 us: docs/physics.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sim.physics.model import GRAVITY, Preset

Array = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Gains:
    """Controller tuning, as bandwidths (rad/s) and damping ratios."""

    pos_bw: float = 3.0
    """Position loop natural frequency, rad/s: kx = m*w^2."""
    pos_zeta: float = 1.0
    """Position loop damping: kv = 2*zeta*m*w."""
    att_bw: float = 15.0
    """Attitude natural frequency, rad/s (limited by motor lag)."""
    att_zeta: float = 0.9
    yaw_bw: float = 5.0
    """Yaw is slower: its torque is small (kappa ~ 2 cm)."""
    int_bw: float = 1.0
    """Integral gain ki = m * int_bw * w^2 / 3 (a third of the position stiffness a second)."""
    err_sat: float = 1.5
    """Horizontal position error saturation, m: cruise speed ~ w * err_sat / (2 zeta) =
    2.25 m/s. 1.5 m moves 3 m in 2.6 s (docs/physics.md) and a standby 7 m to its slot
    in ~4 s (1 m: 5 s), with the same ~1 cm overshoot."""
    err_sat_z: float = 1.0
    """Vertical position error saturation, m (climb ~1.5 m/s). Saturated apart from the
    horizontal error: one 3-D saturation let a 20 m move crawl up at 0.1 m/s, so a
    standby crossed the field at take-off height (0.6 m) and climbed at the end."""
    int_radius: float = 0.2
    """Integrate only within this distance of the target, m ..."""
    int_speed: float = 0.2
    """... and below this speed error, m/s (no wind-up while still arriving)."""
    int_cap: float = 0.3
    """Integral force cap, fraction of the weight."""
    max_tilt: float = math.radians(35.0)
    """Largest tilt of the thrust vector, rad."""


@dataclass(frozen=True, slots=True)
class Command:
    """A setpoint the controller tracks (world frame, z up)."""

    position: Array
    velocity: Array
    acceleration: Array
    yaw: float = 0.0


def _cross(a: Array, b: Array) -> Array:
    return np.array(
        (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
    )


def mixer(p: Preset) -> Array:
    """The 4x4 matrix from motor thrusts to [thrust, Mx, My, Mz]."""
    cols = [(1.0, y, -x, s * p.kappa) for (x, y), s in zip(p.rotors, p.spins, strict=True)]
    return np.array(cols, dtype=np.float64).T


class SE3Controller:
    """One craft's controller. `update` returns the four motor thrusts, N."""

    def __init__(self, p: Preset, gains: Gains | None = None) -> None:
        self.p = p
        self.g = gains or Gains()
        g = self.g
        m = p.mass
        self.kx = m * g.pos_bw**2
        self.kv = 2.0 * g.pos_zeta * m * g.pos_bw
        self.ki = m * g.int_bw * g.pos_bw**2 / 3.0
        j = np.array(p.inertia)
        bw = np.array((g.att_bw, g.att_bw, g.yaw_bw))
        self.kr = j * bw**2
        self.kw = 2.0 * g.att_zeta * j * bw
        self.j = j
        self.mix_inv = np.linalg.inv(mixer(p))
        self.integral = np.zeros(3)
        self.int_limit = g.int_cap * m * GRAVITY

    def reset(self) -> None:
        """Forget the integral (on the ground, or after a new function)."""
        self.integral[:] = 0.0

    def wrench(
        self, pos: Array, vel: Array, rot: Array, omega: Array, cmd: Command, dt: float
    ) -> tuple[float, Array]:
        """Collective thrust (N) and body moments (N m). `rot` is the body-to-world
        rotation (3x3), `omega` the body-frame angular velocity."""
        g = self.g
        m = self.p.mass
        ex, dist = self._position_error(pos, cmd)
        ev = vel - cmd.velocity
        if dist < g.int_radius and float(ev @ ev) < g.int_speed**2:
            self.integral += self.ki * ex * dt
            n = math.sqrt(float(self.integral @ self.integral))
            if n > self.int_limit:
                self.integral *= self.int_limit / n
        force = -self.kx * ex - self.kv * ev - self.integral + m * cmd.acceleration
        force[2] += m * GRAVITY
        # Keep some lift and a bounded tilt: a saturated move must not dive.
        force[2] = max(force[2], 0.3 * m * GRAVITY)
        horiz = math.hypot(force[0], force[1])
        hmax = force[2] * math.tan(g.max_tilt)
        if horiz > hmax:
            force[0] *= hmax / horiz
            force[1] *= hmax / horiz
        b3 = rot[:, 2]
        thrust = float(force @ b3)
        b3d = force / math.sqrt(float(force @ force))
        b1c = np.array((math.cos(cmd.yaw), math.sin(cmd.yaw), 0.0))
        b2d = _cross(b3d, b1c)
        b2d /= math.sqrt(float(b2d @ b2d))
        b1d = _cross(b2d, b3d)
        rd = np.column_stack((b1d, b2d, b3d))
        e = 0.5 * (rd.T @ rot - rot.T @ rd)
        er = np.array((e[2, 1], e[0, 2], e[1, 0]))
        moments = -self.kr * er - self.kw * omega + _cross(omega, self.j * omega)
        return thrust, moments

    def _position_error(self, pos: Array, cmd: Command) -> tuple[Array, float]:
        """The position error, saturated horizontally and vertically, and the distance
        to the setpoint before saturation."""
        g = self.g
        ex = pos - cmd.position
        dist = math.sqrt(float(ex @ ex))
        horiz_err = math.hypot(ex[0], ex[1])
        if horiz_err > g.err_sat:
            ex[0] *= g.err_sat / horiz_err
            ex[1] *= g.err_sat / horiz_err
        if abs(ex[2]) > g.err_sat_z:
            ex[2] = math.copysign(g.err_sat_z, ex[2])
        return ex, dist

    def update(
        self, pos: Array, vel: Array, rot: Array, omega: Array, cmd: Command, dt: float
    ) -> Array:
        """Motor thrusts (N), clipped to the motor range."""
        thrust, moments = self.wrench(pos, vel, rot, omega, cmd, dt)
        f = self.mix_inv @ np.array((thrust, moments[0], moments[1], moments[2]))
        out: Array = np.clip(f, 0.0, self.p.max_thrust)
        return out
