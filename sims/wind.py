"""Wind: a steady wind, Dryden-like turbulence and discrete 1-cosine gusts, seeded.

Turbulence: each NED axis is a first-order Gauss-Markov process, the discrete form of the Dryden
longitudinal spectrum ``H(s) = sigma sqrt(2 L / (pi V)) / (1 + (L / V) s)`` (MIL-F-8785C, sec. 3.7.2;
MIL-HDBK-1797), time constant ``L / V``. Low-altitude scales (MIL-F-8785C, h < 1000 ft, in feet there,
converted here): ``sigma_w = 0.1 W20``, ``sigma_u / sigma_w = 1 / (0.177 + 0.000823 h)^0.4`` and
``L_u = h / (0.177 + 0.000823 h)^1.2``, ``L_w = h``, with ``h`` the height in feet and ``W20`` the wind
speed at 20 ft. The true Dryden lateral and vertical spectra are second order; the first-order
shaping is the usual simulator simplification (it gets the variance and correlation time right).

Discrete gusts: the "1-cosine" shape of MIL-F-8785C sec. 3.7.4 / CS-25.341,
``v(t) = A/2 (1 - cos(2 pi (t - t0) / d))`` for ``t0 <= t <= t0 + d``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

from merlin.core.types import ZERO3, Vec3
from sims.sensors import _BLOCK, normal_rows

_FT: Final = 0.3048
_PREFETCH_AT: Final = 7 * _BLOCK // 8  # the IMU lanes draw at 1/8, 3/8, 5/8 of theirs, the fault noise at 1/2


@dataclass(frozen=True, slots=True)
class DiscreteGust:
    start_s: float
    duration_s: float
    amplitude_ned_mps: Vec3


@dataclass(frozen=True, slots=True)
class WindParams:
    steady_ned_mps: Vec3 = ZERO3
    turbulence_w20_mps: float = 0.0  # wind speed at 6 m (20 ft) for the turbulence intensity; 0 = calm
    turbulence_height_m: float = 10.0  # height the scales are evaluated at
    reference_speed_mps: float = 5.0  # V of the Dryden time constant L / V (airspeed of the vehicle)
    gusts: tuple[DiscreteGust, ...] = ()


def dryden_low_altitude(w20_mps: float, height_m: float) -> tuple[float, float, float, float]:
    """(sigma_u, sigma_w, L_u, L_w) in m/s and m for MIL-F-8785C low-altitude turbulence."""
    h_ft = max(height_m, 3.0) / _FT  # the model is not defined at the ground; floor at 3 m
    k = 0.177 + 0.000823 * h_ft
    sigma_w = 0.1 * w20_mps
    sigma_u = sigma_w / k**0.4
    return sigma_u, sigma_w, h_ft / k**1.2 * _FT, h_ft * _FT


class WindModel:
    """``step(t_s)`` once per simulation tick of ``dt_s``: returns the wind (air velocity) in NED, m/s."""

    __slots__ = ("_g", "_n", "_phi", "_q", "p")

    def __init__(self, params: WindParams, rng: np.random.Generator, dt_s: float) -> None:
        self.p = params
        su, sw, lu, lw = dryden_low_altitude(params.turbulence_w20_mps, params.turbulence_height_m)
        v = max(params.reference_speed_mps, 0.5)
        phi_u, phi_w = math.exp(-dt_s * v / lu), math.exp(-dt_s * v / lw)
        self._phi = (phi_u, phi_u, phi_w)
        self._q = (su * math.sqrt(1 - phi_u**2), su * math.sqrt(1 - phi_u**2), sw * math.sqrt(1 - phi_w**2))
        start = rng.standard_normal(3)
        self._g = [float(start[0]) * su, float(start[1]) * su, float(start[2]) * sw]
        # drawn 1024 rows at a time, the next block at row 7/8 of the current one, so the wind never refills
        # on the same tick as the sensor streams (sims/sensors.py staggered_rows); same values either way
        self._n = normal_rows(rng, 3, _PREFETCH_AT)

    def step(self, t_s: float) -> Vec3:
        n = self._n()
        g, phi, q = self._g, self._phi, self._q
        g[0] = phi[0] * g[0] + q[0] * n[0]
        g[1] = phi[1] * g[1] + q[1] * n[1]
        g[2] = phi[2] * g[2] + q[2] * n[2]
        s = self.p.steady_ned_mps
        x, y, z = s[0] + g[0], s[1] + g[1], s[2] + g[2]
        for gust in self.p.gusts:
            dt = t_s - gust.start_s
            if 0.0 <= dt <= gust.duration_s:
                k = 0.5 * (1.0 - math.cos(2.0 * math.pi * dt / gust.duration_s))
                a = gust.amplitude_ned_mps
                x, y, z = x + k * a[0], y + k * a[1], z + k * a[2]
        return (x, y, z)


def gust_profile(gusts: Sequence[DiscreteGust], t_s: float) -> Vec3:
    """The discrete-gust part alone at ``t_s`` (pure; for tests and plots)."""
    x = y = z = 0.0
    for gust in gusts:
        dt = t_s - gust.start_s
        if 0.0 <= dt <= gust.duration_s:
            k = 0.5 * (1.0 - math.cos(2.0 * math.pi * dt / gust.duration_s))
            x, y, z = (
                x + k * gust.amplitude_ned_mps[0],
                y + k * gust.amplitude_ned_mps[1],
                z + k * gust.amplitude_ned_mps[2],
            )
    return (x, y, z)
