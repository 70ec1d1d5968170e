"""A fence built again over the same zones takes what the first derived (merlin.core.geofence's _derived, kept per process):
the same objects, the same verdicts as a fence derived afresh; other zones or another grid derive their own;
a range that failed to build fails again; the store stays bounded."""

from __future__ import annotations

import math

import pytest

from merlin.core import geofence as gf
from merlin.core.geofence import CircleNE, Fence, FenceParams, PolygonNE, check

MR = FenceParams()
SHELL = ((0.0, 0.0), (600.0, 0.0), (600.0, 250.0), (250.0, 250.0), (250.0, 600.0), (0.0, 600.0))


def _zones(shift: float = 0.0) -> dict[str, object]:
    return {"inclusion_polygons": (PolygonNE(tuple((n + shift, e) for n, e in SHELL)),),
            "exclusion_circles": (CircleNE((150.0 + shift, 400.0), 40.0),)}


def _verdicts(fence: Fence) -> list[gf.FenceResult]:
    """Trips and margins over a sweep of positions and velocities across the notch and the keep-out."""
    out = []
    for n in range(-20, 640, 37):
        for e in range(-20, 640, 41):
            for vn, ve in ((0.0, 0.0), (12.0, -3.0), (-8.0, 15.0)):
                r = check(fence, (float(n), float(e), -30.0), (vn, ve, 0.0), 0.7, 0.7, True)
                out.append(r)
    return out


def test_the_same_zones_share_what_was_derived_and_decide_the_same() -> None:
    gf._derived.cache_clear()
    first = Fence(MR, **_zones())  # type: ignore[arg-type]
    again = Fence(FenceParams(margin_m=8.0), **_zones())  # type: ignore[arg-type]  # other parameters
    # the objects are shared; plain values are equal (the compiled build stores them unboxed: a new tuple or
    # float object at every read)
    shared = {"_allowed", "_forbidden", "_incl_hazard", "_excl_hazard", "_excl_boundary", "_enclosed", "_grid",
              "_arc_tables", "_local"}
    plain = {"_has_inclusion", "_box", "_grid_nj", "_grid_ni", "_grid_inv_cell", "_grid_cell"}
    assert shared | plain == set(gf._DERIVED_FIELDS)
    for name in shared:
        assert getattr(again, name) is getattr(first, name), name
    for name in plain:
        assert getattr(again, name) == getattr(first, name), name
    gf._derived.cache_clear()
    fresh = Fence(FenceParams(margin_m=8.0), **_zones())  # type: ignore[arg-type]
    assert fresh._grid is not again._grid
    assert _verdicts(again) == _verdicts(fresh)


def test_other_zones_or_another_grid_derive_their_own() -> None:
    gf._derived.cache_clear()
    a = Fence(MR, **_zones())  # type: ignore[arg-type]
    b = Fence(MR, **_zones(shift=50.0))  # type: ignore[arg-type]
    c = Fence(MR, grid_cells=1024, **_zones())  # type: ignore[arg-type]
    assert b._grid is not a._grid and c._grid is not a._grid
    assert b._box != a._box and c._grid_ni != a._grid_ni
    assert gf._derived.cache_info().currsize == 3


def test_a_range_that_failed_fails_again() -> None:
    gf._derived.cache_clear()
    everywhere_excluded = {"inclusion_polygons": (PolygonNE(((0.0, 0.0), (10.0, 0.0), (10.0, 10.0))),),
                           "exclusion_circles": (CircleNE((3.0, 3.0), 100.0),)}
    for _ in range(2):
        with pytest.raises(ValueError, match="nowhere is inside the fence"):
            Fence(MR, **everywhere_excluded)  # type: ignore[arg-type]
    assert gf._derived.cache_info().currsize == 0


def test_the_store_keeps_only_the_newest_ranges() -> None:
    gf._derived.cache_clear()
    def build(k: int) -> Fence:
        return Fence(MR, inclusion_circles=(CircleNE((0.0, 0.0), 100.0 + k),), grid_cells=64)

    fences = [build(k) for k in range(gf._DERIVED_MAX + 5)]
    assert gf._derived.cache_info().currsize == gf._DERIVED_MAX
    # the newest ranges are kept (built again, they share the first build's grid), the oldest are not
    kept = range(5, gf._DERIVED_MAX + 5)
    assert all(build(k)._grid is fences[k]._grid for k in kept)
    misses = gf._derived.cache_info().misses
    assert build(0)._grid is not fences[0]._grid
    assert gf._derived.cache_info().misses == misses + 1
    assert all(math.isfinite(fences[k]._grid_cell) for k in kept)
