"""The ground-track plot frames the flight and its nearest fence edges, not the whole range."""

from __future__ import annotations

import itertools

import numpy as np
from shapely.geometry import Point, Polygon

from sims.report import _edge_kinds, _nearest_edges, ground_track_view


def _square_track(side_m: float, n: int = 50) -> np.ndarray:
    """A square flown from home: (north, east) samples along its four sides."""
    corners = np.array([[0, 0], [side_m, 0], [side_m, side_m], [0, side_m], [0, 0]], dtype=float)
    return np.concatenate([np.linspace(a, b, n, endpoint=False) for a, b in itertools.pairwise(corners)])


def test_a_small_flight_in_a_large_range_is_framed_on_itself() -> None:
    range_2km = Point(0.0, 0.0).buffer(2000.0)  # (north, east)
    track = _square_track(20.0)
    edges = _nearest_edges(range_2km, None, track)
    assert len(edges) == 1 and 1960.0 < edges[0][0] < 2000.0  # (the buffer is a 64-gon)
    e0, e1, n0, n1 = ground_track_view(track, edges)
    assert e1 - e0 < 60.0 and n1 - n0 < 60.0  # not a dot in a 4 km frame
    assert e0 <= 0.0 and e1 >= 20.0 and n0 <= 0.0 and n1 >= 20.0


def test_a_near_edge_is_in_view_with_its_kind() -> None:
    field = Polygon([(-100, -100), (-100, 100), (35, 100), (35, -100)])  # north edge 15 m past the track
    barn = Polygon([(5, 40), (5, 60), (15, 60), (15, 40)])  # a keep-out 20 m east of the track
    track = _square_track(20.0)
    edges = _nearest_edges(field, barn, track)
    kinds = _edge_kinds(field, barn, edges)
    assert [round(d, 1) for d, _, _ in edges] == [15.0, 20.0] and kinds == ["inclusion", "keep-out"]
    e0, e1, n0, n1 = ground_track_view(track, edges)
    assert n1 >= 35.0 and e1 >= 40.0  # both edges' nearest points are in view
    assert max(e1 - e0, n1 - n0) <= 2.0 * min(e1 - e0, n1 - n0) + 1e-9  # no narrower than 2:1


def test_a_keep_out_cut_from_the_allowed_area_is_a_keep_out_edge() -> None:
    """The core's allowed area has the keep-out zones cut out of it: their edges are keep-out edges."""
    field = Polygon([(-1000, -500), (-1000, 500), (0, 500), (0, -500)])
    mast = Point(-500.0, -500.0).buffer(80.0)
    allowed = field.difference(mast)
    track = np.array([[-560.0, 0.0], [-300.0, 20.0]])
    edges = _nearest_edges(allowed, mast, track)
    kinds = _edge_kinds(allowed, mast, edges)
    found = dict(zip(kinds, [d for d, _, _ in edges], strict=True))
    assert set(found) == {"inclusion", "keep-out"}
    assert abs(found["inclusion"] - 300.0) < 0.5  # the field's north edge, from (-300, 20)
    assert abs(found["keep-out"] - (np.hypot(60.0, 500.0) - 80.0)) < 1.0  # the mast's circle, from (-560, 0)
