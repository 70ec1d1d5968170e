"""A LiPo battery: open-circuit voltage from the state of charge, sag through an internal resistance.

``V = n_cells * OCV(soc) - I R``, with the current from the electrical power the motors draw,
``I = P / V`` (solved in closed form: ``I = (E - sqrt(E^2 - 4 R P)) / (2 R)``). The per-cell OCV curve
is a typical LiPo discharge curve at low rate (4.20 V full, ~3.7 V over the flat middle, 3.3 V empty).
A sag fault (:class:`BatterySagFault`) adds internal resistance and/or removes capacity over a time
window: the voltage drops under load, the usable thrust with it (``supply_scale``), and the remaining
fraction jumps down, as a damaged or cold pack does.
"""

from __future__ import annotations

import itertools
import math
from bisect import bisect_left
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, NamedTuple

from merlin.core.types import new_record

# (state of charge, cell open-circuit volts), ascending; typical LiPo at C/5 discharge.
LIPO_OCV_CURVE: tuple[tuple[float, float], ...] = (
    (0.00, 3.30),
    (0.05, 3.50),
    (0.10, 3.60),
    (0.20, 3.68),
    (0.40, 3.75),
    (0.60, 3.85),
    (0.80, 3.98),
    (0.95, 4.12),
    (1.00, 4.20),
)


@dataclass(frozen=True, slots=True)
class BatteryParams:
    cells: int = 4  # 4S pack of the default 450-class quad
    capacity_mah: float = 5000.0
    internal_resistance_ohm: float = 0.025  # 4S 5000 mAh 25-35C packs: 15-30 mOhm when new
    drive_efficiency: float = 0.75  # ESC x motor efficiency: electrical power = shaft power / this
    # Below this cell voltage under load the ESCs cannot reach full rotor speed any more; supply_scale
    # = V / (cells * full_authority_cell_v), capped at 1.
    full_authority_cell_v: float = 3.5
    avionics_power_w: float = 5.0  # flight controller, GPS, radio


@dataclass(frozen=True, slots=True)
class BatterySagFault:
    start_s: float
    end_s: float = math.inf
    extra_resistance_ohm: float = 0.0
    capacity_loss_frac: float = 0.0  # of the nominal capacity, while active


class BatteryStatus(NamedTuple):
    """The pack at ``t_s``. A ``NamedTuple``, not a frozen dataclass: one is built every simulator tick, at
    half the cost."""

    t_s: float
    voltage_v: float
    current_a: float
    remaining_frac: float  # state of charge of the usable capacity, 0..1
    consumed_mah: float
    supply_scale: float  # fraction of the nominal maximum rotor speed available (Multirotor.step)


# The curve's segments, for a binary search instead of a walk along them (the pack spends a flight in
# the upper segments, the last ones a walk reaches): the upper state of charge of each segment, and its
# (s0, v0, v1 - v0, s1 - s0). The differences are the ones the interpolation computed each call.
_OCV_UPPER_SOC: Final[tuple[float, ...]] = tuple(s1 for s1, _v1 in LIPO_OCV_CURVE[1:])
_OCV_SEGMENTS: Final[tuple[tuple[float, float, float, float], ...]] = tuple(
    (s0, v0, v1 - v0, s1 - s0) for (s0, v0), (s1, v1) in itertools.pairwise(LIPO_OCV_CURVE)
)


def cell_ocv_v(soc: float) -> float:
    s = soc if soc > 0.0 else 0.0  # max(0.0, soc), NaN -> 0.0
    if not s < 1.0:
        s = 1.0
    i = bisect_left(_OCV_UPPER_SOC, s)  # the first segment with s <= s1
    if i < len(_OCV_SEGMENTS):
        s0, v0, dv, ds = _OCV_SEGMENTS[i]
        return v0 + dv * (s - s0) / ds
    return LIPO_OCV_CURVE[-1][1]


class Battery:
    """``step(shaft_power_w, t_s, dt_s) -> BatteryStatus``; the pack starts full unless told otherwise."""

    __slots__ = ("_consumed_mah", "_faults", "p")

    def __init__(
        self, params: BatteryParams, faults: Sequence[BatterySagFault] = (), initial_frac: float = 1.0
    ) -> None:
        self.p = params
        self._faults = tuple(faults)
        self._consumed_mah = params.capacity_mah * (1.0 - min(1.0, max(0.0, initial_frac)))

    def step(self, shaft_power_w: float, t_s: float, dt_s: float) -> BatteryStatus:
        # Runs every simulator tick: ``x if x > 0.0 else 0.0`` is ``max(0.0, x)`` (NaN -> 0.0 too) and
        # ``x if x < 1.0 else 1.0`` is ``min(1.0, x)``, without the builtin calls.
        p = self.p
        r = p.internal_resistance_ohm
        cap = p.capacity_mah
        for f in self._faults:
            if f.start_s <= t_s < f.end_s:
                r += f.extra_resistance_ohm
                cap *= max(0.0, 1.0 - f.capacity_loss_frac)
        if cap > 0.0:
            soc = 1.0 - self._consumed_mah / cap
            soc = soc if soc > 0.0 else 0.0
        else:
            soc = 0.0
        e = p.cells * cell_ocv_v(soc)
        pw = (shaft_power_w if shaft_power_w > 0.0 else 0.0) / p.drive_efficiency + p.avionics_power_w
        disc = e * e - 4.0 * r * pw
        if disc <= 0.0:  # the pack cannot deliver this power: it collapses to the maximum-power point
            current = e / (2.0 * r)
        else:
            current = (e - math.sqrt(disc)) / (2.0 * r)
        v = e - current * r
        consumed = self._consumed_mah = self._consumed_mah + current * dt_s / 3.6
        if cap > 0.0:
            soc = 1.0 - consumed / cap
            soc = soc if soc > 0.0 else 0.0
        else:
            soc = 0.0
        scale = v / (p.cells * p.full_authority_cell_v)
        scale = scale if scale > 0.0 else 0.0
        scale = scale if scale < 1.0 else 1.0
        return new_record(BatteryStatus, (t_s, v, current, soc, consumed, scale))
