"""WGS84 <-> local NED about home (azimuthal equidistant on WGS84, via pyproj)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyproj import Geod

from merlin.geodesy import LocalFrame

GEOD = Geod(ellps="WGS84")
HOMES = [
    (29.6516, -82.3248, 30.0),  # Gainesville (the config default)
    (0.0, 0.0, 0.0),
    (-45.0, 170.0, 1200.0),
    (64.8, -147.7, 140.0),  # Fairbanks: high latitude
    (51.5, 179.99, 10.0),  # next to the antimeridian
]


def _random_local(rng: np.random.Generator, count: int, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    r = radius_m * np.sqrt(rng.uniform(0.0, 1.0, count))
    a = rng.uniform(-math.pi, math.pi, count)
    return r * np.cos(a), r * np.sin(a)


@pytest.mark.parametrize("home", HOMES)
def test_round_trip_below_a_millimetre_within_10_km(home: tuple[float, float, float]) -> None:
    frame = LocalFrame(*home)
    rng = np.random.default_rng(7)
    north, east = _random_local(rng, 2000, 10_000.0)
    down = rng.uniform(-500.0, 50.0, north.shape)
    lat, lon, alt = frame.geodetic_from_ned(np.stack([north, east, down], axis=-1))
    back = frame.ned_from_geodetic(lat, lon, alt)
    err = np.hypot(np.hypot(back[:, 0] - north, back[:, 1] - east), back[:, 2] - down)
    assert float(err.max()) < 1e-3


@pytest.mark.parametrize("home", HOMES)
def test_distances_match_the_geodesic_within_a_tenth_of_a_percent(home: tuple[float, float, float]) -> None:
    frame = LocalFrame(*home)
    rng = np.random.default_rng(11)
    n1, e1 = _random_local(rng, 500, 10_000.0)
    n2, e2 = _random_local(rng, 500, 10_000.0)
    lat1, lon1 = frame.latlon_from_ne(n1, e1)
    lat2, lon2 = frame.latlon_from_ne(n2, e2)
    _, _, geodesic = GEOD.inv(lon1, lat1, lon2, lat2)
    local = np.hypot(n2 - n1, e2 - e1)
    keep = geodesic > 1.0
    assert float(np.max(np.abs(local[keep] / geodesic[keep] - 1.0))) < 1e-3
    # from home itself the projection is exact (equidistant), and bearings are preserved
    _, _, from_home = GEOD.inv(np.full_like(lon1, home[1]), np.full_like(lat1, home[0]), lon1, lat1)
    assert np.allclose(np.hypot(n1, e1), from_home, rtol=1e-9, atol=1e-6)


def test_axes_are_north_east_down() -> None:
    frame = LocalFrame(29.6516, -82.3248, 30.0)
    north_pt = frame.to_ned(29.6616, -82.3248, 40.0)
    assert north_pt[0] > 1000.0 and abs(north_pt[1]) < 1e-6 and north_pt[2] == pytest.approx(-10.0)
    east_pt = frame.to_ned(29.6516, -82.3148)
    assert east_pt[1] > 900.0 and abs(east_pt[0]) < 1.0 and east_pt[2] == 0.0
    assert frame.to_ned(29.6516, -82.3248, 30.0) == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    _, _, dist = GEOD.inv(-82.3248, 29.6516, -82.3248, 29.6616)
    assert north_pt[0] == pytest.approx(dist, rel=1e-9)


@settings(max_examples=200, deadline=None)
@given(
    north=st.floats(-10_000.0, 10_000.0), east=st.floats(-10_000.0, 10_000.0), down=st.floats(-3000.0, 100.0)
)
def test_scalar_and_vector_conversions_agree(north: float, east: float, down: float) -> None:
    frame = LocalFrame(29.6516, -82.3248, 30.0)
    lat, lon, alt = frame.to_geodetic(north, east, down)
    vlat, vlon, valt = frame.geodetic_from_ned([north, east, down])
    assert (lat, lon, alt) == pytest.approx((float(vlat), float(vlon), float(valt)), abs=1e-12)
    n2, e2, d2 = frame.to_ned(lat, lon, alt)
    assert math.hypot(n2 - north, e2 - east) < 1e-3 and d2 == pytest.approx(down, abs=1e-9)


def test_vectorised_shapes_and_bad_input() -> None:
    frame = LocalFrame(10.0, 20.0, 5.0)
    lat = np.full((3, 4), 10.001)
    lon = np.full((3, 4), 20.001)
    ned = frame.ned_from_geodetic(lat, lon, 6.0)
    assert ned.shape == (3, 4, 3) and np.allclose(ned[..., 2], -1.0)
    with pytest.raises(ValueError, match="last axis"):
        frame.geodetic_from_ned(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="latitude"):
        LocalFrame(91.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="longitude"):
        LocalFrame(0.0, math.nan, 0.0)
    assert "LocalFrame(lat0_deg=10.0" in repr(frame)
