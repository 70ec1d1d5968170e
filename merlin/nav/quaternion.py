"""Unit-quaternion and rotation helpers for the navigation filter.

Convention (Hamilton, as in Solà 2017, "Quaternion kinematics for the error-state Kalman filter",
arXiv:1711.02508, sec. 2-4): ``q = [w, x, y, z]``, ``q`` rotates body FRD vectors into NED,
``v_ned = R(q) v_frd``; composition ``q_a ⊗ q_b``; ``Exp(φ)`` maps a rotation vector to a quaternion
(Solà eq. 101). Euler angles are the aerospace 3-2-1 (yaw, pitch, roll) sequence used by PX4/MAVLink.
Written with plain floats where the filter calls them every IMU tick: for 3- and 4-element vectors the
numpy call overhead dominates the arithmetic.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np

# math functions with no native form in mypyc, bound once: compiled, reading a module's attribute costs
# more than the call (docs/benchmarks/sim.md, "Module constants, enum members and math functions in the tick")
_atan2: Final = math.atan2
_asin: Final = math.asin

Quat = tuple[float, float, float, float]


def quat_mul(a: Quat, b: Quat) -> Quat:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_normalize(q: Quat) -> Quat:
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[0] < 0.0:  # keep the scalar part positive: one representative per rotation
        n = -n
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def quat_exp(phi_x: float, phi_y: float, phi_z: float) -> Quat:
    """Quaternion of the rotation vector φ (Solà eq. 101)."""
    angle = math.sqrt(phi_x * phi_x + phi_y * phi_y + phi_z * phi_z)
    if angle < 1e-9:
        # second-order series keeps the small-step integration accurate and avoids 0/0
        return quat_normalize((1.0 - angle * angle / 8.0, 0.5 * phi_x, 0.5 * phi_y, 0.5 * phi_z))
    s = math.sin(0.5 * angle) / angle
    return (math.cos(0.5 * angle), phi_x * s, phi_y * s, phi_z * s)


def quat_log(q: Quat) -> tuple[float, float, float]:
    """Rotation vector of a unit quaternion (inverse of :func:`quat_exp`, Solà eq. 105)."""
    w, x, y, z = quat_normalize(q)
    vn = math.sqrt(x * x + y * y + z * z)
    if vn < 1e-12:
        return (2.0 * x, 2.0 * y, 2.0 * z)
    angle = 2.0 * _atan2(vn, w)
    return (x * angle / vn, y * angle / vn, z * angle / vn)


def quat_conj(q: Quat) -> Quat:
    return (q[0], -q[1], -q[2], -q[3])


def quat_to_dcm(q: Quat) -> np.ndarray:
    """R(q), body -> NED (Solà eq. 115)."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_rotate(q: Quat, v: tuple[float, float, float]) -> tuple[float, float, float]:
    """R(q) v without building the matrix (the hot path of the mechanisation)."""
    w, x, y, z = q
    vx, vy, vz = v
    # t = 2 q_v × v ; v' = v + w t + q_v × t
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (
        vx + w * tx + (y * tz - z * ty),
        vy + w * ty + (z * tx - x * tz),
        vz + w * tz + (x * ty - y * tx),
    )


def quat_from_euler(roll_rad: float, pitch_rad: float, yaw_rad: float) -> Quat:
    cr, sr = math.cos(0.5 * roll_rad), math.sin(0.5 * roll_rad)
    cp, sp = math.cos(0.5 * pitch_rad), math.sin(0.5 * pitch_rad)
    cy, sy = math.cos(0.5 * yaw_rad), math.sin(0.5 * yaw_rad)
    return quat_normalize(
        (
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        )
    )


def quat_to_euler(q: Quat) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of the 3-2-1 sequence; pitch clamped at ±90°."""
    w, x, y, z = q
    roll = _atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = _asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = _atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return (roll, pitch, yaw)


def dcm_from_euler(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    return quat_to_dcm(quat_from_euler(roll_rad, pitch_rad, yaw_rad))


def skew(v: np.ndarray | tuple[float, float, float]) -> np.ndarray:
    """[v]×, so that skew(a) @ b == cross(a, b)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def wrap_pi(angle_rad: float) -> float:
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi
