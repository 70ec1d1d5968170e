"""Wind (turbulence statistics, 1-cosine gusts, determinism) and the battery (sag, consumption, faults)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from sims.battery import LIPO_OCV_CURVE, Battery, BatteryParams, BatterySagFault, cell_ocv_v
from sims.wind import DiscreteGust, WindModel, WindParams, dryden_low_altitude, gust_profile

DT = 0.0025


def wind_series(params: WindParams, seconds: float, seed: int = 0) -> np.ndarray:
    w = WindModel(params, np.random.default_rng(seed), DT)
    return np.array([w.step(i * DT) for i in range(round(seconds / DT))])


def test_calm_is_exactly_the_steady_wind() -> None:
    s = wind_series(WindParams(steady_ned_mps=(3.0, -1.0, 0.0)), 1.0)
    assert np.all(s == np.array([3.0, -1.0, 0.0]))


def test_turbulence_has_the_dryden_intensity() -> None:
    p = WindParams(turbulence_w20_mps=10.0, turbulence_height_m=10.0, reference_speed_mps=20.0)
    su, sw, lu, lw = dryden_low_altitude(10.0, 10.0)
    assert sw == pytest.approx(1.0) and su > sw and lu > lw  # horizontal stronger and longer than vertical
    s = np.concatenate([wind_series(p, 60.0, seed) for seed in range(3)])
    assert s[:, 0].std() == pytest.approx(su, rel=0.2)
    assert s[:, 2].std() == pytest.approx(sw, rel=0.2)
    assert abs(s[:, 0].mean()) < 0.5 * su


def test_one_minus_cosine_gust_shape() -> None:
    g = DiscreteGust(start_s=1.0, duration_s=2.0, amplitude_ned_mps=(0.0, 6.0, 0.0))
    assert gust_profile([g], 0.99) == (0.0, 0.0, 0.0)
    assert gust_profile([g], 2.0) == pytest.approx((0.0, 6.0, 0.0))  # peak at mid-duration
    assert gust_profile([g], 1.5) == pytest.approx((0.0, 3.0, 0.0))
    assert gust_profile([g], 3.01) == (0.0, 0.0, 0.0)
    s = wind_series(WindParams(gusts=(g,)), 4.0)
    assert s[:, 1].max() == pytest.approx(6.0, abs=1e-4)


def test_wind_is_deterministic_per_seed() -> None:
    p = WindParams(turbulence_w20_mps=8.0)
    assert np.array_equal(wind_series(p, 3.0, 5), wind_series(p, 3.0, 5))
    assert not np.array_equal(wind_series(p, 3.0, 5), wind_series(p, 3.0, 6))


HOVER_SHAFT_W = 143.0  # 4 x k_m w^3 at hover on the default vehicle


def test_battery_sags_under_load_and_drains() -> None:
    p = BatteryParams()
    idle = Battery(p).step(0.0, 0.0, DT)
    load = Battery(p).step(HOVER_SHAFT_W, 0.0, DT)
    assert idle.voltage_v == pytest.approx(4 * 4.2, abs=0.05)
    assert load.voltage_v < idle.voltage_v - 0.2  # I R sag
    assert load.current_a == pytest.approx(
        (HOVER_SHAFT_W / p.drive_efficiency + p.avionics_power_w) / load.voltage_v
    )
    b = Battery(p)
    for i in range(round(60.0 / 0.1)):  # one minute of hover
        s = b.step(HOVER_SHAFT_W, i * 0.1, 0.1)
    assert s.consumed_mah == pytest.approx(s.current_a * 60.0 / 3.6, rel=0.05)
    assert 0.9 < s.remaining_frac < 1.0
    # a 450 quad on 5000 mAh hovers ~20 min: the pack is 1/20 used per minute (+-30 %)
    assert 1.0 - s.remaining_frac == pytest.approx(1.0 / 20.0, rel=0.3)
    assert s.supply_scale == 1.0


def test_sag_fault_drops_voltage_capacity_and_authority() -> None:
    fault = BatterySagFault(start_s=1.0, extra_resistance_ohm=0.5, capacity_loss_frac=0.5)
    b = Battery(BatteryParams(), [fault])
    before = b.step(HOVER_SHAFT_W, 0.5, DT)
    after = b.step(HOVER_SHAFT_W, 1.5, DT)
    assert after.voltage_v < before.voltage_v - 3.0
    assert after.remaining_frac < before.remaining_frac
    assert after.supply_scale < 1.0


def test_ocv_curve_is_monotonic() -> None:
    v = [cell_ocv_v(s) for s in np.linspace(0.0, 1.0, 101)]
    assert all(b >= a for a, b in itertools.pairwise(v))
    assert v[0] == 3.3 and v[-1] == 4.2
    assert not math.isnan(cell_ocv_v(float("nan")))


def _ocv_by_walking(soc: float) -> float:
    """The OCV lookup as first written: walk the segments, take the first with soc <= its upper end."""
    s = min(1.0, max(0.0, soc))
    for (s0, v0), (s1, v1) in itertools.pairwise(LIPO_OCV_CURVE):
        if s <= s1:
            return v0 + (v1 - v0) * (s - s0) / (s1 - s0)
    return LIPO_OCV_CURVE[-1][1]


def test_ocv_binary_search_is_the_segment_walk_bit_for_bit() -> None:
    knots = [s for s, _ in LIPO_OCV_CURVE]
    socs = [*np.linspace(-0.2, 1.2, 2001).tolist(), *knots, math.nan, math.inf, -math.inf, -0.0]
    socs += [math.nextafter(s, d) for s in knots for d in (-1.0, 2.0)]
    for soc in socs:
        assert cell_ocv_v(soc) == _ocv_by_walking(soc), soc
