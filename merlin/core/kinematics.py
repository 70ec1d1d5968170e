"""Kinematics shared by the core's command shaping and the trusted behaviours: a proportional position law,
the straight-line braking stop, and one tick of an acceleration limit. Pure functions of tuples (three-element
vectors are cheaper as tuples than as numpy arrays at this size)."""

from __future__ import annotations

import math
from typing import Final

from merlin.core.types import Vec3, VehicleState

# math functions with no native form in mypyc, bound once: compiled, reading a module's attribute costs
# more than the call (docs/benchmarks/sim.md, "Module constants, enum members and math functions in the tick")
_hypot: Final = math.hypot


def position_to_velocity(
    target: Vec3,
    pos: Vec3,
    ff: Vec3,
    gain_per_s: float,
    max_h_mps: float,
    max_up_mps: float,
    max_down_mps: float,
) -> Vec3:
    """P law from position error to a velocity setpoint, horizontally and vertically speed-limited."""
    vn = ff[0] + gain_per_s * (target[0] - pos[0])
    ve = ff[1] + gain_per_s * (target[1] - pos[1])
    vd = ff[2] + gain_per_s * (target[2] - pos[2])
    h = _hypot(vn, ve)
    if h > max_h_mps:
        k = max_h_mps / h
        vn, ve = vn * k, ve * k
    vd = min(max(vd, -max_up_mps), max_down_mps)
    return (vn, ve, vd)


def stopping_point(s: VehicleState, decel_mps2: float) -> Vec3:
    """Where the vehicle comes to rest if it brakes now at ``decel_mps2`` (horizontal and vertical).

    Horizontally along its velocity, ``v |v| / (2 a)``: the straight braking path the fence projection
    assumes (:func:`merlin.core.geofence.check`). Braking each axis on its own would aim the stop off that
    path, and the vehicle would curve past the projected stop towards the boundary it approaches at an angle.
    """
    p, v = s.pos_ned_m, s.vel_ned_mps
    k = 1.0 / (2.0 * decel_mps2)
    kh = _hypot(v[0], v[1]) * k
    return (p[0] + v[0] * kh, p[1] + v[1] * kh, p[2] + v[2] * abs(v[2]) * k)


def limit_velocity_change(prev: Vec3, target: Vec3, max_dh_mps: float, max_dv_mps: float) -> Vec3:
    """Move from ``prev`` towards ``target`` by at most ``max_dh_mps`` horizontally and ``max_dv_mps``
    vertically: one tick of an acceleration limit."""
    dn, de, dd = target[0] - prev[0], target[1] - prev[1], target[2] - prev[2]
    h = _hypot(dn, de)
    if h > max_dh_mps:
        dn, de = dn * max_dh_mps / h, de * max_dh_mps / h
    dd = min(max(dd, -max_dv_mps), max_dv_mps)
    return (prev[0] + dn, prev[1] + de, prev[2] + dd)
