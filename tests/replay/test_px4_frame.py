"""PX4's local frame (spherical azimuthal equidistant about the log's reference point) and the replay's
placement of a log's positions in Merlin's frame about the configuration's home."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.models import MerlinConfig
from merlin.geodesy import LocalFrame
from merlin.replay.core_replay import home_frame
from merlin.replay.flightlog import FlightLog
from merlin.replay.px4_frame import Px4MapProjection

HOME = (29.6516, -82.3248, 30.0)


def px4_project(ref_lat: float, ref_lon: float, lat: float, lon: float) -> tuple[float, float]:
    """PX4's map_projection project(), written out from its formulas (src/lib/geo)."""
    r = 6371000.0
    la, lo, rla, rlo = map(math.radians, (lat, lon, ref_lat, ref_lon))
    cos_d_lon = math.cos(lo - rlo)
    arg = min(1.0, max(-1.0, math.sin(rla) * math.sin(la) + math.cos(rla) * math.cos(la) * cos_d_lon))
    c = math.acos(arg)
    k = c / math.sin(c) if abs(c) > 0 else 1.0
    return (k * (math.cos(rla) * math.sin(la) - math.sin(rla) * math.cos(la) * cos_d_lon) * r,
            k * math.cos(la) * math.sin(lo - rlo) * r)


@settings(max_examples=60, deadline=None)
@given(st.floats(-60.0, 60.0), st.floats(-179.0, 179.0), st.floats(-5000.0, 5000.0), st.floats(-5000.0, 5000.0))
def test_projection_is_px4s(ref_lat: float, ref_lon: float, north: float, east: float) -> None:
    lat, lon = LocalFrame(ref_lat, ref_lon).latlon_from_ne(north, east)
    x, y = Px4MapProjection(ref_lat, ref_lon).project(lat, lon)
    ex, ey = px4_project(ref_lat, ref_lon, float(lat), float(lon))
    assert abs(float(x) - ex) < 1e-4 and abs(float(y) - ey) < 1e-4
    back = Px4MapProjection(ref_lat, ref_lon).reproject(x, y)
    assert abs(float(back[0]) - float(lat)) < 1e-10 and abs(float(back[1]) - float(lon)) < 1e-10


def test_merlin_and_px4_frames_differ_by_the_earth_model() -> None:
    lat, lon = LocalFrame(HOME[0], HOME[1]).latlon_from_ne(1000.0, 0.0)
    x, _ = Px4MapProjection(HOME[0], HOME[1]).project(lat, lon)
    assert round(float(x), 1) == 1003.1


def _cfg() -> MerlinConfig:
    return MerlinConfig.model_validate({"home": {"lat_deg": HOME[0], "lon_deg": HOME[1], "alt_amsl_m": HOME[2]}})


def _px4_log(ref: tuple[float, float, float], lat: np.ndarray, lon: np.ndarray, alt: np.ndarray) -> FlightLog:
    x, y = Px4MapProjection(ref[0], ref[1]).project(lat, lon)
    t = np.arange(len(lat), dtype=float)
    pos = np.stack([x, y, ref[2] - alt], axis=1)
    zeros = np.zeros((len(t), 3))
    return FlightLog("px4.ulg", "ulog", (t, pos), (t, zeros), (t, zeros), ref_lat_deg=ref[0], ref_lon_deg=ref[1],
                     ref_alt_m=ref[2], local_frame="px4")


def test_a_px4_log_is_placed_where_it_flew_against_home() -> None:
    home = LocalFrame(*HOME)
    north = np.array([0.0, 400.0, 1200.0, -800.0])
    east = np.array([0.0, 300.0, -900.0, 1500.0])
    lat, lon = home.latlon_from_ne(north, east)
    alt = np.array([30.0, 50.0, 80.0, 42.0])
    # the estimator's origin: where PX4 first had GPS, 250 m north and 120 m west of home, 2 m higher
    rlat, rlon = home.latlon_from_ne(250.0, -120.0)
    log = _px4_log((float(rlat), float(rlon), 32.0), lat, lon, alt)
    placed, choice = home_frame(log, _cfg())
    assert choice.frame == "home" and "PX4's spherical map_projection" in choice.text
    pos = placed.pos_ned_m[1]
    assert np.allclose(pos[:, 0], north, atol=1e-3) and np.allclose(pos[:, 1], east, atol=1e-3)
    assert np.allclose(pos[:, 2], HOME[2] - alt, atol=1e-6)
    assert choice.max_shift_m > 250.0  # the origin's offset, and the projections' difference on top
    as_is, choice = home_frame(log, _cfg(), "log")
    assert choice.frame == "log" and as_is.pos_ned_m[1] is log.pos_ned_m[1]


def test_a_log_from_elsewhere_keeps_its_own_frame_unless_asked() -> None:
    lat, lon = np.array([47.397742]), np.array([8.545594])  # PX4 SITL's default origin, Zurich
    log = _px4_log((47.397742, 8.545594, 488.0), lat, lon, np.array([488.0]))
    _, choice = home_frame(log, _cfg())
    assert choice.frame == "log" and "km from the configuration's home" in choice.text
    _, forced = home_frame(log, _cfg(), "home")
    assert forced.frame == "home" and forced.max_shift_m > 7.0e6
