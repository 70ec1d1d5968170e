"""The airspace boundary failsafe: a geofence checked with velocity projection.

Merlin paper, "Additional system failsafes", Figure 4: a position-only fence (Fig. 4b) triggers when the
aircraft is already outside, so a fast aircraft "will continue past the boundary while the autopilot
applies opposing control effort"; the velocity-projection fence (Fig. 4a) "triggers the failsafe such that
the aircraft will remain within the boundary using the maximum available control effort", and "is
parameterized such that vehicles of different configuration (fixed or rotary)" can fly near the boundary.

The projection used here (the paper gives no formula; this is the plainest model that meets its claim):

* Multirotor: it can stop. The projected stopping path is the straight segment from the position along
  the horizontal velocity, of length ``d = v * t_react + v**2 / (2 * a_max)`` (constant speed during the
  reaction time, then braking at the deceleration the trusted autopilot can hold).
* Fixed wing: it cannot stop. The projected path is a straight reaction leg ``v * t_react`` and then a
  half circle at the bank limit, radius ``R = v**2 / (g * tan(bank))``, reversing the heading. It may turn
  either way, so it trips only when *neither* the left nor the right turn stays clear.
* The path trips when it comes within ``margin_m + sigma_k * sigma_h`` (the widening: a fixed keep-clear
  margin plus k standard deviations of the horizontal position estimate) of a hazard: the boundary of the
  inclusion zones (a union, as in PX4: inside any one is inside) or any exclusion zone. Being outside
  already always trips.
* Altitude: a ceiling, and a floor that applies only when airborne, with the vertical stopping distance
  ``vz * t_react + vz**2 / (2 * a_v_max)`` towards the limit, widened by ``margin_m + sigma_k * sigma_v``.
* Position-only mode (paper Fig. 4b, kept for comparison): trips only when the position itself is outside
  the fence, inside an exclusion zone, or beyond an altitude limit; no projection and no widening.

Geometry is local NED metres about home (shapely x = north, y = east: a mirror image of the map, which
changes no distance and no containment). Circles are polygonised conservatively: inclusion circles by an
inscribed polygon, exclusion circles by a circumscribed one, chord error below ``CIRCLE_CHORD_ERROR_M``.

Speed (the whole core tick has a 50 µs median budget; shapely calls cost several µs each), in layers
that each answer "clear" only when the exact test would, so the verdict never depends on them (a property
test compares with and without, and with plain shapely):

1. A distance field built with the fence: the distance from each grid cell's centre to the forbidden
   area. ``field(centre) - |x - centre|`` bounds the distance from any point x (triangle inequality).
   One lookup clears a path that lies within its reach of the position (most ticks, no shapely call).
2. Otherwise the path is covered by discs (segment halves; arc pieces; the turn circle) and each disc
   checked against the field, halving up to ``_GRID_DEPTH`` times (pure Python, still no shapely).
3. Otherwise the exact test: ``shapely.dwithin`` of the path (a segment; for a fixed wing each turn as a
   polyline) against the forbidden area clipped to a tile around the position (a few vertices instead
   of the whole fence; sound because the path cannot reach anything outside the tile).
4. Only on a trip, the clearance: sphere tracing along the path on exact distances, then bisection.

See ``docs/benchmarks/geofence.md`` for the figures.

Everything here is pure: a :class:`Fence` is built once, outside the tick, and never changes.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Final, Literal, NamedTuple

import numpy as np
import numpy.typing as npt
import shapely

from merlin.core.types import defined_native, new_record, set_frozen_fields
from merlin.core.types import finite as _isfinite

# math functions with no native form in mypyc, bound once: compiled, reading a module's attribute costs
# more than the call (docs/benchmarks/sim.md, "Module constants, enum members and math functions in the tick")
_hypot: Final = math.hypot
_acos: Final = math.acos
_radians: Final = math.radians

#: whether this module is mypyc's extension module (``merlin.core.types``: the records' own ``__init__``)
NATIVE: Final = defined_native(lambda: None)

FenceModeName = Literal["velocity_projection", "position_only"]
VehicleKind = Literal["multirotor", "fixed_wing"]
FenceKind = Literal["", "outside", "inclusion", "exclusion", "ceiling", "floor", "invalid"]

STANDARD_GRAVITY_MPS2: Final = 9.80665

#: Largest distance between a fence circle and the polygon standing for it (the task asks < 0.1 m).
CIRCLE_CHORD_ERROR_M: Final = 0.05
#: Largest distance between the fixed-wing turn arc and its polyline; it is added to the widening so the
#: polyline test is never less cautious than the arc would be.
ARC_CHORD_ERROR_M: Final = 0.05
_ARC_SEGMENT_CHOICES = (8, 16, 32, 64, 128, 256)

#: Inputs beyond these are not a vehicle state but a broken estimate: the check trips with kind "invalid".
#: 1e7 m is a quarter of the Earth's circumference (the local projection means nothing farther out).
MAX_ABS_POS_M: Final = 1.0e7
MAX_SPEED_MPS: Final = 1.0e3
MAX_SIGMA_M: Final = 1.0e6

#: Cells of the distance field built with each fence (0 disables layers 1 and 2 of the pre-check).
DEFAULT_GRID_CELLS: Final = 16_384
#: Reach levels (m) of the local hazard tiles: square blocks of this side, each holding the forbidden area
#: clipped to the block grown by the level on every side. A path whose reach plus widening fits in a
#: level is tested against that small clipped geometry instead of the whole fence (same answer, less
#: GEOS work). A level needing more than ``_MAX_BLOCKS_PER_LEVEL`` blocks is skipped.
_LOCAL_LEVELS_M = (64.0, 128.0, 256.0)
_MAX_BLOCKS_PER_LEVEL: Final = 4096
#: Bisection resolution of the clearance reported on a trip (absolute, and relative to the path length).
_CLEARANCE_RESOLUTION_M: Final = 0.01
#: A projected path shorter than this is tested as a point (see ``_path_hits``).
_MIN_PATH_M: Final = 1.0e-6
#: Sphere-tracing steps towards the first contact before bisection takes over.
_TRACE_STEPS: Final = 8
_TINY: Final = 1.0e-100

_NAN: Final = math.nan
_INF: Final = math.inf

FloatArray = npt.NDArray[np.float64]
PointNE = tuple[float, float]


# ------------------------------------------------------------------------------------------ parameters


def _reduce_by_fields(obj: Any) -> tuple[Any, tuple[Any, ...]]:
    """Pickling of this module's frozen dataclasses: rebuilt by their constructor from their fields.

    Written out because the compiled build (mypyc) makes them native classes whose default pickling
    restores the fields one ``setattr`` at a time, which a frozen dataclass refuses.
    """
    return type(obj), tuple(getattr(obj, f.name) for f in fields(obj))


@dataclass(frozen=True, slots=True)
class FenceParams:
    """How the fence is checked. SI units and radians (degrees are converted in ``merlin.config``).

    Defaults mirror :class:`merlin.config.models.GeofenceConfig` and ``VehicleLimits``, except ``margin_m``:
    the configuration's default is 8 m (cross-check XC012, docs/crosschecks.md), the 5 m here is what the
    core's own tests are written against.
    """

    mode: FenceModeName = "velocity_projection"
    margin_m: float = 5.0
    sigma_k: float = 2.0
    altitude_floor_m: float | None = None  # height above home; None: no floor
    altitude_ceiling_m: float | None = 120.0  # height above home; None: no ceiling
    vehicle: VehicleKind = "multirotor"
    reaction_time_s: float = 0.3
    max_h_decel_mps2: float = 4.0
    max_v_decel_mps2: float = 3.0
    bank_limit_rad: float = _radians(35.0)
    gravity_mps2: float = STANDARD_GRAVITY_MPS2
    enabled: bool = True
    # Multirotor: the largest acceleration a command can demand during the reaction time (horizontally
    # g tan(max tilt), vertically the climb/sink acceleration limit); see ``demand_vel_ned_mps`` of check().
    max_h_accel_mps2: float = STANDARD_GRAVITY_MPS2 * math.tan(_radians(45.0))  # VehicleLimits.max_tilt_deg
    max_v_accel_mps2: float = 4.0
    # Fixed wing: how the trusted loops fly the escape turn (:func:`fixed_wing_turn`). Below
    # ``full_bank_airspeed_mps`` they hold the wings (nearly) level and regain speed towards
    # ``turn_airspeed_mps`` at the speed loop's first-order rate ``turn_speed_gain_per_s``; the turn is
    # then flown at the bank limit at ``turn_airspeed_mps`` (or the current airspeed, if faster). 0 for
    # both airspeeds: the turn at the current airspeed, at once (no speed to regain).
    full_bank_airspeed_mps: float = 0.0
    turn_airspeed_mps: float = 0.0
    turn_speed_gain_per_s: float = 0.6
    # Fixed wing: the rate at which the trusted loops move their bank (the roll setpoint's slew). A bank away
    # from a turn's side is rolled out at it before the roll-in that the reaction time covers
    # (:func:`fixed_wing_turn`). 0: not modelled (the escape starts from wings level).
    roll_rate_radps: float = 0.0
    # Fixed wing: the most height the stall recovery may lose after a revocation (derived from the aircraft
    # and the envelope: merlin.autopilot.fixedwing_recovery.recovery_height_bound_m). The floor projection
    # counts it beyond the reaction time's sink, so that a controller granted above the minimum grant height
    # is revoked while the recovery still keeps the floor. 0: no recovery to allow for (a multirotor brakes).
    recovery_height_m: float = 0.0
    # Fixed wing: the steepest bank the trusted loops fly (their own bank limit, which may be steeper than
    # ``bank_limit_rad``, the bank the projection's turn assumes). The inner edge of each side's swept area
    # (:func:`fixed_wing_turn`): a turn begun at once at this bank (or the bank held now, if steeper) on the
    # side of the turn, at the slower of the airspeed and ``full_bank_airspeed_mps``. 0: not modelled (the
    # projection's turn alone).
    turn_bank_max_rad: float = 0.0

    def __post_init__(self) -> None:
        problems: list[str] = []
        if self.mode not in ("velocity_projection", "position_only"):
            problems.append(f"mode {self.mode!r} is not 'velocity_projection' or 'position_only'")
        if self.vehicle not in ("multirotor", "fixed_wing"):
            problems.append(f"vehicle {self.vehicle!r} is not 'multirotor' or 'fixed_wing'")
        for name in ("margin_m", "sigma_k", "reaction_time_s", "recovery_height_m", "roll_rate_radps"):
            v = getattr(self, name)
            if not (_isfinite(v) and v >= 0.0):
                problems.append(f"{name}={v!r} must be finite and >= 0")
        for name in ("full_bank_airspeed_mps", "turn_airspeed_mps"):
            v = getattr(self, name)
            if not (_isfinite(v) and 0.0 <= v <= MAX_SPEED_MPS):
                problems.append(f"{name}={v!r} must be finite and in [0, {MAX_SPEED_MPS:g}]")
        if self.full_bank_airspeed_mps > 0.0 and not (self.turn_airspeed_mps > self.full_bank_airspeed_mps):
            problems.append(f"turn_airspeed_mps ({self.turn_airspeed_mps!r}) must be above full_bank_airspeed_mps "
                            f"({self.full_bank_airspeed_mps!r}) when that is given (the speed loop never reaches "
                            "its own target)")
        for name in ("max_h_decel_mps2", "max_v_decel_mps2", "gravity_mps2", "max_h_accel_mps2", "max_v_accel_mps2",
                     "turn_speed_gain_per_s"):
            v = getattr(self, name)
            if not (_isfinite(v) and v > 0.0):
                problems.append(f"{name}={v!r} must be finite and > 0")
        if not (0.0 < self.bank_limit_rad < 0.5 * math.pi):
            problems.append(f"bank_limit_rad={self.bank_limit_rad!r} must be in (0, pi/2)")
        if not (0.0 <= self.turn_bank_max_rad < 0.5 * math.pi):
            problems.append(f"turn_bank_max_rad={self.turn_bank_max_rad!r} must be in [0, pi/2)")
        for name in ("altitude_floor_m", "altitude_ceiling_m"):
            v = getattr(self, name)
            if v is not None and not _isfinite(v):
                problems.append(f"{name}={v!r} must be finite or None")
        f, c = self.altitude_floor_m, self.altitude_ceiling_m
        if f is not None and c is not None and f >= c:
            problems.append(f"altitude_floor_m ({f}) must be below altitude_ceiling_m ({c})")
        if problems:
            raise ValueError("invalid FenceParams: " + "; ".join(problems))

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        return _reduce_by_fields(self)


# ------------------------------------------------------------------------------------------- geometry


@dataclass(frozen=True, slots=True)
class PolygonNE:
    """A polygon in the local frame: shell and holes as (north_m, east_m) vertices (closing vertex optional)."""

    shell_ne_m: tuple[PointNE, ...]
    holes_ne_m: tuple[tuple[PointNE, ...], ...] = ()

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        return _reduce_by_fields(self)


@dataclass(frozen=True, slots=True)
class CircleNE:
    center_ne_m: PointNE
    radius_m: float

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        return _reduce_by_fields(self)


@dataclass(frozen=True, slots=True)
class PolygonProblem:
    """Why a polygon cannot be a fence zone; ``at_ne_m`` locates the defect when GEOS reports it."""

    text: str
    at_ne_m: PointNE | None = None


_GEOS_LOCATION: Final = re.compile(r"\[\s*([-+0-9.eEinfa]+)\s+([-+0-9.eEinfa]+)")


def polygon_problem(
    shell_ne_m: Sequence[Sequence[float]], holes_ne_m: Sequence[Sequence[Sequence[float]]] = ()
) -> PolygonProblem | None:
    """None if the polygon is usable as a fence zone, else what is wrong with it (used by the builders)."""
    rings = [shell_ne_m, *holes_ne_m]
    for k, ring in enumerate(rings):
        what = "polygon" if k == 0 else f"hole {k - 1}"
        if len(ring) < 3:
            return PolygonProblem(f"{what} needs at least 3 vertices, got {len(ring)}")
        for v in ring:
            if len(v) != 2 or not all(_isfinite(x) for x in v):
                return PolygonProblem(f"{what} vertex {list(v)} is not a finite (north, east) pair")
    shell = shapely.Polygon([tuple(v) for v in shell_ne_m])
    if float(shapely.area(shapely.convex_hull(shell))) <= 1e-9:
        return PolygonProblem("polygon has zero area (its vertices are collinear or coincident)")
    for k, hole in enumerate(holes_ne_m):
        h = shapely.Polygon([tuple(v) for v in hole])
        if float(shapely.area(shapely.convex_hull(h))) <= 1e-9:
            return PolygonProblem(f"hole {k} has zero area (its vertices are collinear or coincident)")
    poly = shapely.Polygon([tuple(v) for v in shell_ne_m], [[tuple(v) for v in h] for h in holes_ne_m])
    reason = str(shapely.is_valid_reason(poly))
    if reason == "Valid Geometry":
        if float(shapely.area(poly)) <= 1e-9:
            return PolygonProblem("polygon has zero area")
        return None
    at: PointNE | None = None
    m = _GEOS_LOCATION.search(reason)
    if m is not None:
        try:
            at = (float(m.group(1)), float(m.group(2)))
        except ValueError:
            at = None
    if "Self-intersection" in reason:
        return PolygonProblem("polygon is self-intersecting", at)
    if "Hole lies outside shell" in reason:
        return PolygonProblem("a hole lies outside the polygon", at)
    if "nested" in reason.lower():
        return PolygonProblem("holes are nested inside each other", at)
    if "disconnected" in reason.lower():
        return PolygonProblem("the holes cut the polygon into disconnected parts", at)
    return PolygonProblem(f"polygon is not valid ({reason.split('[')[0]})", at)


def circle_vertex_count(radius_m: float, chord_error_m: float = CIRCLE_CHORD_ERROR_M) -> int:
    """Vertices for a polygon within ``chord_error_m`` of a circle, inscribed or circumscribed."""
    # Circumscribed: vertices at R / cos(pi/n), outward error R (1/cos(pi/n) - 1); the inscribed error
    # R (1 - cos(pi/n)) is smaller, so one count serves both.
    half_angle = _acos(radius_m / (radius_m + chord_error_m))
    return max(16, math.ceil(math.pi / half_angle))


def circle_polygon_ne(circle: CircleNE, *, circumscribed: bool) -> list[PointNE]:
    """The polygon standing for a fence circle: inscribed (inclusion) or circumscribed (exclusion)."""
    r = circle.radius_m
    n = circle_vertex_count(r)
    rv = r / math.cos(math.pi / n) if circumscribed else r
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    cn, ce = circle.center_ne_m
    return list(zip((cn + rv * np.cos(a)).tolist(), (ce + rv * np.sin(a)).tolist(), strict=True))


def _polygon_geom(p: PolygonNE, where: str) -> Any:
    problem = polygon_problem(p.shell_ne_m, p.holes_ne_m)
    if problem is not None:
        at = (
            f" at north {problem.at_ne_m[0]:.3f} m, east {problem.at_ne_m[1]:.3f} m"
            if problem.at_ne_m
            else ""
        )
        raise ValueError(f"{where}: {problem.text}{at}")
    return shapely.Polygon([tuple(v) for v in p.shell_ne_m], [[tuple(v) for v in h] for h in p.holes_ne_m])


def _circle_geom(c: CircleNE, where: str, *, circumscribed: bool) -> Any:
    if not (_isfinite(c.radius_m) and c.radius_m > 0.0 and all(_isfinite(x) for x in c.center_ne_m)):
        raise ValueError(
            f"{where}: circle centre {c.center_ne_m} / radius {c.radius_m} must be finite, r > 0"
        )
    return shapely.Polygon(circle_polygon_ne(c, circumscribed=circumscribed))


# ---------------------------------------------------------------------------------------------- fence


@dataclass(frozen=True, slots=True, eq=False)
class Fence:
    """An immutable fence: zones in the local frame plus the check parameters. Build once, outside the tick.

    Inclusion zones form a union (inside any one is inside); exclusion zones are keep-out areas. Without
    any inclusion zone only the exclusion zones and the altitude limits apply. ``grid_cells`` sizes the
    distance field of the fast pre-check (0 disables it; verdicts are identical either way).
    """

    params: FenceParams
    inclusion_polygons: tuple[PolygonNE, ...] = ()
    inclusion_circles: tuple[CircleNE, ...] = ()
    exclusion_polygons: tuple[PolygonNE, ...] = ()
    exclusion_circles: tuple[CircleNE, ...] = ()
    grid_cells: int = DEFAULT_GRID_CELLS
    # ---- derived once in __post_init__ (shapely geometries are prepared) ----
    _has_inclusion: bool = field(init=False, repr=False)
    _allowed: Any = field(init=False, repr=False)  # inclusion union minus exclusions; None without inclusions
    _forbidden: Any = field(init=False, repr=False)  # everything to keep clear of (within the box); or None
    _incl_hazard: Any = field(init=False, repr=False)  # box minus the inclusion union; or None
    _excl_hazard: Any = field(init=False, repr=False)  # exclusion union; or None
    _excl_boundary: Any = field(init=False, repr=False)
    # the forbidden area's bounded parts (the allowed area's holes: keep-outs inside it; every exclusion zone
    # without inclusion zones); or None. Only these can lie inside a fixed wing's swept area whose boundary
    # keeps clear (:func:`_encloses`).
    _enclosed: Any = field(init=False, repr=False)
    _box: tuple[float, float, float, float] = field(init=False, repr=False)  # n0, e0, n1, e1
    _grid: tuple[float, ...] = field(init=False, repr=False)
    _grid_nj: int = field(init=False, repr=False)
    _grid_ni: int = field(init=False, repr=False)
    _grid_inv_cell: float = field(init=False, repr=False)
    _grid_cell: float = field(init=False, repr=False)
    _arc_tables: tuple[tuple[int, float, FloatArray, FloatArray], ...] = field(init=False, repr=False)
    _local: tuple[_LocalLevel, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        derived = _derived(self.inclusion_polygons, self.inclusion_circles, self.exclusion_polygons,
                           self.exclusion_circles, self.grid_cells)
        for name, value in zip(_DERIVED_FIELDS, derived, strict=True):
            object.__setattr__(self, name, value)

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        # Pickled (e.g. to a worker process) as the values of every field, derived ones included, so unpickling does not rebuild the geometry and the grid. Written
        # out rather than left to the dataclass machinery because the compiled build (mypyc) makes this a
        # native class, which neither ``copy.copy`` nor the default slot-state restore can set up.
        return _fence_from_fields, (tuple(getattr(self, name) for name in _FENCE_FIELDS),)

    def with_params(self, params: FenceParams) -> Fence:
        """The same zones checked with other parameters (shares the prepared geometry and the grid)."""
        values = [getattr(self, name) for name in _FENCE_FIELDS]
        values[0] = params
        return _fence_with_fields(values)

    @property
    def has_inclusion(self) -> bool:
        return self._has_inclusion

    @property
    def allowed_area(self) -> Any:
        """The inclusion union minus the exclusions (shapely, x = north), or None without inclusion zones."""
        return self._allowed

    @property
    def exclusion_area(self) -> Any:
        """The union of the exclusion zones (shapely, x = north), or None."""
        return self._excl_hazard


#: Every field of :class:`Fence`, derived ones included, in declaration order (``params`` first).
_FENCE_FIELDS: Final[tuple[str, ...]] = tuple(f.name for f in fields(Fence))
#: The fields ``__post_init__`` derives from the zones and ``grid_cells`` (the parameters play no part).
_DERIVED_FIELDS: Final[tuple[str, ...]] = tuple(f.name for f in fields(Fence) if not f.init)

_DERIVED_MAX: Final = 16


@functools.lru_cache(maxsize=_DERIVED_MAX)
def _derived(inclusion_polygons: tuple[PolygonNE, ...], inclusion_circles: tuple[CircleNE, ...],
             exclusion_polygons: tuple[PolygonNE, ...], exclusion_circles: tuple[CircleNE, ...],
             grid_cells: int) -> tuple[Any, ...]:
    """What a :class:`Fence` derives from its zones and ``grid_cells`` (the parameters play no part): the
    geometries, the distance grid and the local levels, one value per :data:`_DERIVED_FIELDS`.

    Kept per process by zones and grid: a process flying many runs over one range (a campaign worker, a test
    worker) builds the same fence for each, and this costs about 190 million instructions, more than a
    simulated second of the nominal loop (docs/benchmarks/sim.md, "Counting instructions"). Everything derived
    is immutable and already shared between fences (:meth:`Fence.with_params`). A range that fails raises and
    is not kept: given again, it is validated again.
    """
    out: dict[str, Any] = {}
    incl = [_polygon_geom(p, f"inclusion_polygons[{i}]") for i, p in enumerate(inclusion_polygons)]
    incl += [
        _circle_geom(c, f"inclusion_circles[{i}]", circumscribed=False)
        for i, c in enumerate(inclusion_circles)
    ]
    excl = [_polygon_geom(p, f"exclusion_polygons[{i}]") for i, p in enumerate(exclusion_polygons)]
    excl += [
        _circle_geom(c, f"exclusion_circles[{i}]", circumscribed=True)
        for i, c in enumerate(exclusion_circles)
    ]
    excl_union = shapely.union_all(excl) if excl else None
    incl_hazard = None
    if incl:
        incl_union = shapely.union_all(incl)
        allowed = incl_union if excl_union is None else shapely.difference(incl_union, excl_union)
        if shapely.is_empty(allowed) or float(shapely.area(allowed)) <= 0.0:
            raise ValueError(
                "the exclusion zones cover every inclusion zone: nowhere is inside the fence"
            )
        n0, e0, n1, e1 = (float(x) for x in shapely.bounds(incl_union))
        # The forbidden area is a box around the inclusion zones minus the allowed area: a path leaving
        # the fence crosses the ring between them; a position beyond the box is outside by a compare.
        pad = max(100.0, 0.1 * max(n1 - n0, e1 - e0))
        box = (n0 - pad, e0 - pad, n1 + pad, e1 + pad)
        box_geom = shapely.box(*box)
        forbidden = shapely.difference(box_geom, allowed)
        incl_hazard = shapely.difference(box_geom, incl_union)
    else:
        allowed = None
        forbidden = excl_union
        if excl_union is not None:
            n0, e0, n1, e1 = (float(x) for x in shapely.bounds(excl_union))
            pad = max(100.0, 0.1 * max(n1 - n0, e1 - e0))
            box = (n0 - pad, e0 - pad, n1 + pad, e1 + pad)
        else:
            box = (0.0, 0.0, 0.0, 0.0)
    excl_boundary = shapely.boundary(excl_union) if excl_union is not None else None
    enclosed = excl_union
    if allowed is not None:
        holes = [shapely.polygons(shapely.get_interior_ring(part, i))
                 for part in shapely.get_parts(allowed) for i in range(shapely.get_num_interior_rings(part))]
        enclosed = shapely.union_all(holes) if holes else None
    for g in (allowed, forbidden, incl_hazard, excl_union, excl_boundary, enclosed):
        if g is not None:
            shapely.prepare(g)
    out["_has_inclusion"] = bool(incl)
    out["_allowed"] = allowed
    out["_forbidden"] = forbidden
    out["_incl_hazard"] = incl_hazard
    out["_excl_hazard"] = excl_union
    out["_excl_boundary"] = excl_boundary
    out["_enclosed"] = enclosed
    out["_box"] = box
    grid, ni, nj, inv_cell = _build_grid(allowed, forbidden, box, grid_cells)
    out["_grid"] = grid
    out["_grid_ni"] = ni
    out["_grid_nj"] = nj
    out["_grid_inv_cell"] = inv_cell
    out["_grid_cell"] = 1.0 / inv_cell if inv_cell > 0.0 else 0.0
    tables = []
    for m in _ARC_SEGMENT_CHOICES:
        phi = np.linspace(0.0, math.pi, m + 1)
        tables.append((m, 1.0 - math.cos(0.5 * math.pi / m), np.cos(phi), np.sin(phi)))
    out["_arc_tables"] = tuple(tables)
    out["_local"] = _build_local_levels(forbidden, box)
    return tuple(out[name] for name in _DERIVED_FIELDS)


def _fence_with_fields(values: Sequence[Any]) -> Fence:
    """A :class:`Fence` holding exactly ``values`` (one per :data:`_FENCE_FIELDS`), ``__post_init__`` not run."""
    new: Fence = Fence.__new__(Fence)
    for name, value in zip(_FENCE_FIELDS, values, strict=True):
        object.__setattr__(new, name, value)
    return new


def _fence_from_fields(values: Sequence[Any]) -> Fence:
    """Unpickling: the fence from its field values, its shapely geometries prepared again (pickling keeps
    the geometries but not their prepared indexes, without which the check is slow)."""
    new = _fence_with_fields(values)
    geoms = [new._allowed, new._forbidden, new._incl_hazard, new._excl_hazard, new._excl_boundary, new._enclosed]
    geoms += [t for lv in new._local for t in lv.tiles]
    live = [g for g in geoms if g is not None]
    if live:
        shapely.prepare(np.array(live, dtype=object))
    return new


def _build_grid(
    allowed: Any, forbidden: Any, box: tuple[float, float, float, float], cells: int
) -> tuple[tuple[float, ...], int, int, float]:
    """The distance from each cell's centre to ``forbidden``; -inf where the centre is not allowed.

    For any point x, ``dist(x, forbidden) >= dist(centre, forbidden) - |x - centre|`` (the triangle
    inequality): a lower bound anywhere, tightest near the centre (see :func:`_lower_bound`).
    """
    n0, e0, n1, e1 = box
    if forbidden is None or cells <= 0 or n1 <= n0 or e1 <= e0:
        return (), 0, 0, 0.0
    cell = math.sqrt((n1 - n0) * (e1 - e0) / cells)
    ni = max(1, math.ceil((n1 - n0) / cell))
    nj = max(1, math.ceil((e1 - e0) / cell))
    cn = n0 + (np.arange(ni) + 0.5) * cell
    ce = e0 + (np.arange(nj) + 0.5) * cell
    gn, ge = np.meshgrid(cn, ce, indexing="ij")
    gn, ge = gn.ravel(), ge.ravel()
    if allowed is not None:
        inside = shapely.contains_xy(allowed, gn, ge)
    else:
        inside = ~shapely.intersects_xy(forbidden, gn, ge)
    dist = np.full(gn.shape, -np.inf)
    if np.any(inside):
        # For an allowed point the distance to the forbidden area is the distance to its boundary (the
        # allowed area's boundary, which excludes the outer box ring, and is quicker to measure).
        edge = shapely.boundary(allowed if allowed is not None else forbidden)
        pts = shapely.points(np.stack((gn[inside], ge[inside]), axis=1))
        dist[inside] = shapely.distance(edge, pts)
    lb = dist - 1e-6  # a micrometre for the rounding of the distances and of the centres
    lb[~(lb > 0.0)] = -np.inf
    return tuple(lb.tolist()), ni, nj, 1.0 / cell


@dataclass(frozen=True, slots=True)
class _LocalLevel:
    """Forbidden area clipped per block: valid for paths whose reach plus widening is <= ``reach_m``."""

    reach_m: float
    inv_block: float
    ni: int
    nj: int
    tiles: tuple[Any, ...]  # prepared clipped geometry per block, or None: nothing forbidden within reach

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        return _reduce_by_fields(self)


def _build_local_levels(forbidden: Any, box: tuple[float, float, float, float]) -> tuple[_LocalLevel, ...]:
    n0, e0, n1, e1 = box
    if forbidden is None or n1 <= n0 or e1 <= e0:
        return ()
    levels = []
    for reach in _LOCAL_LEVELS_M:
        ni = math.ceil((n1 - n0) / reach)
        nj = math.ceil((e1 - e0) / reach)
        if ni * nj > _MAX_BLOCKS_PER_LEVEL:
            continue
        # Each block grown by the reach, and by a millimetre so rounding at the edge never loses a point.
        bi, bj = np.meshgrid(np.arange(ni), np.arange(nj), indexing="ij")
        lo_n = n0 + bi.ravel() * reach - reach - 1e-3
        lo_e = e0 + bj.ravel() * reach - reach - 1e-3
        rects = shapely.box(lo_n, lo_e, lo_n + 3.0 * reach + 2e-3, lo_e + 3.0 * reach + 2e-3)
        touching = shapely.intersects(forbidden, rects)
        tiles: list[Any] = [None] * (ni * nj)
        for k in np.flatnonzero(touching).tolist():
            xmin, ymin, xmax, ymax = shapely.bounds(rects[k]).tolist()
            g = shapely.clip_by_rect(forbidden, xmin, ymin, xmax, ymax)
            if not shapely.is_empty(g):
                shapely.prepare(g)
                tiles[k] = g
        levels.append(_LocalLevel(reach, 1.0 / reach, ni, nj, tuple(tiles)))
    return tuple(levels)


_NOTHING_NEAR: Final = object()


def _local_hazard(fence: Fence, n: float, e: float, need_m: float) -> Any:
    """The forbidden area, clipped around (n, e) when a tile covers ``need_m``; ``_NOTHING_NEAR`` if empty.

    Sound because every forbidden point within ``need_m`` of a position in a block lies in that block's
    tile (the block grown by the level's reach): the clipped and the full area give the same distance
    answer for any path that stays within ``need_m - widening`` of the position.
    """
    n0, e0, n1, e1 = fence._box
    if n0 <= n < n1 and e0 <= e < e1:
        for lv in fence._local:
            if need_m <= lv.reach_m:
                i = min(int((n - n0) * lv.inv_block), lv.ni - 1)
                j = min(int((e - e0) * lv.inv_block), lv.nj - 1)
                tile = lv.tiles[i * lv.nj + j]
                return _NOTHING_NEAR if tile is None else tile
    return fence._forbidden


# ---------------------------------------------------------------------------------------------- result


@dataclass(frozen=True, slots=True, init=False, eq=False)
class FenceResult:
    """The verdict of one :func:`check`.

    ``kind``: which limit tripped, "" when clear. "outside" (already outside the fence or inside an
    exclusion zone), "inclusion"/"exclusion" (the projected path reaches that boundary), "ceiling",
    "floor", or "invalid" (non-finite or absurd inputs: treated as a trip so the core never acts on them).
    ``stopping_distance_m`` (the value): the projected distance used, along the path (fixed wing: the
    reaction leg plus the half-turn arc), or the vertical stopping distance for "ceiling"/"floor"; 0 in
    position-only mode. ``clearance_m`` (the limit): computed only on a trip, NaN otherwise; the distance
    available along the projected path before it comes within the widening of the hazard (the better
    turn for a fixed wing), or the vertical room minus the widening. A trip means value >= limit; for
    "outside" the clearance is the (negative) signed margin minus the widening.
    """

    tripped: bool
    kind: FenceKind
    stopping_distance_m: float
    clearance_m: float

    def __init__(self, tripped: bool, kind: FenceKind, stopping_distance_m: float, clearance_m: float) -> None:
        if NATIVE:
            self.tripped = tripped  # type: ignore[misc]
            self.kind = kind  # type: ignore[misc]
            self.stopping_distance_m = stopping_distance_m  # type: ignore[misc]
            self.clearance_m = clearance_m  # type: ignore[misc]
        else:
            set_frozen_fields(self, (tripped, kind, stopping_distance_m, clearance_m))

    # NaN is this record's "not computed" (the clearance when clear, both figures when invalid): two
    # verdicts that leave the same figures out are the same verdict. The generated comparison got that
    # only from the identity of the module's one NaN object, which the compiled build (floats stored
    # unboxed, a new object at every read) does not keep; hence the comparison and the hash written out.
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FenceResult):
            return False
        return (self.tripped == other.tripped and self.kind == other.kind
                and _same_figure(self.stopping_distance_m, other.stopping_distance_m)
                and _same_figure(self.clearance_m, other.clearance_m))

    def __hash__(self) -> int:
        return hash((self.tripped, self.kind, _figure_key(self.stopping_distance_m), _figure_key(self.clearance_m)))

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        return _reduce_by_fields(self)


def _same_figure(a: float, b: float) -> bool:
    return a == b or (a != a and b != b)


def _figure_key(a: float) -> float | None:
    return None if a != a else a


_INVALID: Final = FenceResult(True, "invalid", _NAN, _NAN)
_DISABLED: Final = FenceResult(False, "", 0.0, _NAN)
_CLEAR_POSITION_ONLY: Final = FenceResult(False, "", 0.0, _NAN)


# ----------------------------------------------------------------------------------------------- check


def check(fence: Fence, pos_ned_m: Sequence[float], vel_ned_mps: Sequence[float], sigma_h_m: float,
          sigma_v_m: float, airborne: bool, wind_ne_mps: tuple[float, float] = (0.0, 0.0),
          demand_vel_ned_mps: Sequence[float] | None = None, bank_rad: float = 0.0) -> FenceResult:
    """The fence verdict for one tick. Pure; never raises on non-finite numbers (they trip "invalid").

    ``demand_vel_ned_mps`` (multirotor): the velocity the command being flown drives towards (for an
    attitude command, the velocity its tilt gives after the reaction time). Commanded intent counts: during
    the reaction time the vehicle keeps accelerating towards it, at most at ``max_h_accel_mps2`` (and
    ``max_v_accel_mps2`` vertically), so the projected path is the reaction leg flown at constant
    acceleration, ``(v + v_r) t_react / 2``, then braking from ``v_r`` along ``v_r`` (a two-segment path
    whose first leg's chord lies within ``|v_r - v| t_react / 8`` of the parabola, added to the widening).
    Only a demand that raises the speed changes the path: braking is never credited. Without it (None), or
    for a fixed wing, the path is the constant-speed one. Scenarios ``adv_velocity_step_*`` and
    ``adv_tilt_step_*`` pin it.

    ``wind_ne_mps`` (fixed wing only): the horizontal wind. A fixed wing turns at its bank limit in the
    *air*: over the reaction leg and the half turn the wind carries it ``wind * t`` downwind, so the ground
    path is the air path plus that drift (a trochoid), not a circle (:func:`_turn_path`; scenario
    ``fw_adv_tailwind_fence_22mps``, docs/fixed-wing.md, "Wind"). A non-finite wind trips "invalid" like any
    broken input: treating it as none would be unsafe.

    ``bank_rad`` (fixed wing only; right positive): the bank at this tick. A turn away from it first rolls
    it out (:func:`fixed_wing_turn`); a non-finite bank trips "invalid". The escape is flown at the
    airspeed, not its horizontal part: in a dive the speed is kept when the loops level the path, and the
    turn is as wide as that speed makes it (scenario ``fw_adv_dive_reversal``)."""
    prm = fence.params
    if not prm.enabled:
        return _DISABLED
    n, e, dn = pos_ned_m
    vn, ve, vd = vel_ned_mps
    wn, we = wind_ne_mps
    if _broken(n, e, dn, vn, ve, vd, sigma_h_m, sigma_v_m, wn, we) or not _isfinite(bank_rad):
        return _INVALID
    n, e, vn, ve = _flush_tiny(n, e, vn, ve)
    v = _hypot(vn, ve)
    if v > MAX_SPEED_MPS:
        return _INVALID
    h = -dn

    if prm.mode == "position_only":
        return _check_position_only(fence, n, e, h, airborne)

    tr = prm.reaction_time_s
    w = prm.margin_m + prm.sigma_k * sigma_h_m
    fixed_wing = prm.vehicle == "fixed_wing"
    wind = _NO_WIND
    if fixed_wing:
        fw = _fixed_wing_projection(fence, vn, ve, vd, v, wn, we, bank_rad)
        if fw is None:
            return _INVALID
        vn, ve, v, wind, turn, d, drift, reach, sag = fw
        leg, radius = turn.leg_m, turn.radius_m
    else:
        turn = None
        leg = radius = sag = drift = 0.0
        d = v * tr + v * v / (2.0 * prm.max_h_decel_mps2)
        reach = d
        if demand_vel_ned_mps is not None:
            dvn, dve, dvd = demand_vel_ned_mps
            if not _isfinite(dvn + dve + dvd) or abs(dvn) > MAX_SPEED_MPS or abs(dve) > MAX_SPEED_MPS or (
                    abs(dvd) > MAX_SPEED_MPS):  # three compares, not a generic max() call (compiled, per tick)
                return _INVALID
            demand = _demanded_path(n, e, vn, ve, v, dvn, dve, prm)
            if demand is not None:
                return _check_demand(fence, n, e, h, vd, -dvd, sigma_v_m, airborne, w, demand)

    return _verdict(fence, n, e, h, vn, ve, vd, v, d, leg, radius, w, sag, reach, turn, wind, drift,
                    sigma_v_m, airborne)


def _fixed_wing_projection(fence: Fence, vn: float, ve: float, vd: float, v: float, wn: float, we: float,
                           bank_rad: float) -> tuple[float, float, float, tuple[float, float], FixedWingTurn, float,
                                                     float, float, float] | None:
    """A fixed wing's escape for :func:`check`: the air velocity (ground velocity less the wind: the turn
    is flown in the air mass, its shape follows the air velocity) and its horizontal speed, the wind, the
    turn, the path length, the wind's drift, the reach (the farthest point of either turn plus the drift)
    and the polylines' chord error; None for a wind beyond :data:`MAX_SPEED_MPS` (invalid)."""
    prm = fence.params
    wind = _NO_WIND
    if wn != 0.0 or we != 0.0:
        if abs(wn) > MAX_SPEED_MPS or abs(we) > MAX_SPEED_MPS:
            return None
        vn, ve = vn - wn, ve - we
        if -_TINY < vn < _TINY:
            vn = 0.0
        if -_TINY < ve < _TINY:
            ve = 0.0
        v = _hypot(vn, ve)
        wind = (wn, we)
    turn = fixed_wing_turn(prm, _escape_speed_mps(v, vd), bank_rad)
    leg, radius = turn.leg_m, turn.radius_m
    rollout = turn.rollout_m()
    d = rollout + leg + math.pi * radius
    drift = _drift_m(wind, turn)
    # farthest point of either turn from the position, plus the drift over the whole manoeuvre (the
    # roll-out's path length bounds how far it moves the turn's start)
    reach = rollout + _hypot(leg, radius) + radius + drift
    # the polyline's chord error (beyond the finest table only for turns wider than ~2.6 km)
    sag = _WIND_SAG_FACTOR * max(ARC_CHORD_ERROR_M, radius * fence._arc_tables[-1][1]) + _leg_sag_m(turn)
    return vn, ve, v, wind, turn, d, drift, reach, sag


def _flush_tiny(n: float, e: float, vn: float, ve: float) -> tuple[float, float, float, float]:
    """Values within :data:`_TINY` of zero as zero: physically zero, but GEOS's arithmetic on such numbers
    underflows and raises floating-point flags."""
    return (0.0 if -_TINY < n < _TINY else n, 0.0 if -_TINY < e < _TINY else e,
            0.0 if -_TINY < vn < _TINY else vn, 0.0 if -_TINY < ve < _TINY else ve)


def _broken(n: float, e: float, dn: float, vn: float, ve: float, vd: float, sigma_h_m: float, sigma_v_m: float,
            wn: float, we: float) -> bool:
    """Inputs that are not a vehicle state but a broken estimate (the check trips "invalid")."""
    # One sum catches any NaN or infinity (and sums overflowing to inf, which the bounds would reject).
    if not _isfinite(n + e + dn + vn + ve + vd + sigma_h_m + sigma_v_m + wn + we):
        return True
    return (
        abs(n) > MAX_ABS_POS_M
        or abs(e) > MAX_ABS_POS_M
        or abs(dn) > MAX_ABS_POS_M
        or abs(vd) > MAX_SPEED_MPS
        or not (0.0 <= sigma_h_m <= MAX_SIGMA_M)
        or not (0.0 <= sigma_v_m <= MAX_SIGMA_M)
    )


def _check_position_only(fence: Fence, n: float, e: float, h: float, airborne: bool) -> FenceResult:
    """The position-only fence (the paper's baseline): the position itself against the boundaries."""
    prm = fence.params
    ceiling, floor = prm.altitude_ceiling_m, prm.altitude_floor_m
    if fence._forbidden is not None and not (_lower_bound(fence, n, e) > 0.0) and not _inside(fence, n, e):
        return FenceResult(True, "outside", 0.0, _signed_h(fence, n, e))
    if ceiling is not None and h >= ceiling:
        return FenceResult(True, "ceiling", 0.0, ceiling - h)
    if airborne and floor is not None and h <= floor:
        return FenceResult(True, "floor", 0.0, h - floor)
    return _CLEAR_POSITION_ONLY


def _floor_drop_m(prm: FenceParams, vd: float) -> float:
    """The height the vehicle may still lose after a floor trip from sink ``vd`` (down positive): the sink
    over the reaction time, then the multirotor's braking at ``max_v_decel_mps2``, or for a fixed wing the
    larger of that and the stall recovery's height loss ``recovery_height_m`` (the bound from any state the
    envelope allows, so that the floor trips before a descent leaves the recovery too little room: scenario
    ``fw_adv_descend_after_grant``)."""
    down = vd if vd > 0.0 else 0.0
    stop = down * down / (2.0 * prm.max_v_decel_mps2)
    return down * prm.reaction_time_s + (stop if stop > prm.recovery_height_m else prm.recovery_height_m)


def _verdict(
    fence: Fence, n: float, e: float, h: float, vn: float, ve: float, vd: float, v: float, d: float, leg: float,
    radius: float, w: float, sag: float, reach: float, turn: FixedWingTurn | None, wind: tuple[float, float],
    drift: float, sigma_v_m: float, airborne: bool,
) -> FenceResult:
    """The projected path (horizontal, then ceiling and floor) against the fence, and the tripped kind with its
    clearance (computed only on a trip: it is the costly part). ``turn``: the fixed wing's escape (None: a
    multirotor's straight braking path)."""
    prm = fence.params
    fixed_wing = turn is not None
    tr = prm.reaction_time_s
    ceiling, floor = prm.altitude_ceiling_m, prm.altitude_floor_m
    trip_h = False
    if fence._forbidden is not None:
        lb = _lower_bound(fence, n, e)
        if not (lb > reach + w + sag):
            if _outside_box(fence, n, e):
                trip_h = True
            elif fence._grid_nj and _grid_clears_path(fence, n, e, vn, ve, v, d, leg, radius, w, fixed_wing, drift,
                                                        turn):
                trip_h = False
            else:
                trip_h = _path_hits(fence, n, e, vn, ve, v, d, turn, w, sag, reach, wind)

    wv = prm.margin_m + prm.sigma_k * sigma_v_m
    trip_c = trip_f = False
    dv_up = dv_down = 0.0
    if ceiling is not None:
        up = -vd if vd < 0.0 else 0.0
        dv_up = up * tr + up * up / (2.0 * prm.max_v_decel_mps2)
        trip_c = h + dv_up + wv >= ceiling
    if airborne and floor is not None:
        dv_down = _floor_drop_m(prm, vd)
        trip_f = h - dv_down - wv <= floor

    if not (trip_h or trip_c or trip_f):
        return FenceResult(False, "", d, _NAN)
    # ---- tripped: classify and compute the clearance (costly, but only now) ----
    if trip_h and not _inside(fence, n, e):
        return FenceResult(True, "outside", d, _signed_h(fence, n, e) - w)
    if trip_c:
        assert ceiling is not None
        return FenceResult(True, "ceiling", dv_up, ceiling - h - wv)
    if trip_f:
        assert floor is not None
        return FenceResult(True, "floor", dv_down, h - floor - wv)
    # Coordinates near the underflow range make GEOS raise floating-point flags; the answers stay sound.
    with np.errstate(all="ignore"):
        kind, clearance = _projected_clearance(fence, n, e, vn, ve, v, d, turn, w, sag, reach, wind)
    return FenceResult(True, kind, d, clearance)


class _DemandPath(NamedTuple):
    """The multirotor's projected path when its command demands more speed: reaction leg, then braking.

    Its three vertices (the position, the end of the reaction leg, the stop) are kept as floats: far from
    the fence, as on most ticks, the grid's lower bound clears the path without reading them, and an array
    of them is built only for the exact geometry (:func:`_demand_verts`)."""

    n0: float
    e0: float
    n1: float
    e1: float
    n2: float
    e2: float
    length_m: float
    sag_m: float  # the reaction leg's chord against the parabola flown


def _demand_verts(path: _DemandPath) -> FloatArray:
    """The path's vertices as a (3, 2) array, for shapely."""
    return np.array(((path.n0, path.e0), (path.n1, path.e1), (path.n2, path.e2)))


def _demanded_path(
    n: float, e: float, vn: float, ve: float, v: float, dvn: float, dve: float, prm: FenceParams
) -> _DemandPath | None:
    """The path of :func:`check` under a speed-raising demand, or None when the demand does not raise it."""
    tr = prm.reaction_time_s
    an, ae = dvn - vn, dve - ve
    a = _hypot(an, ae)
    cap = prm.max_h_accel_mps2 * tr
    if a > cap:
        an, ae = an * cap / a, ae * cap / a
        a = cap
    rn, re_ = vn + an, ve + ae
    vr = _hypot(rn, re_)
    if not (vr > v + 1e-9):
        return None
    n1, e1 = n + 0.5 * (vn + rn) * tr, e + 0.5 * (ve + re_) * tr
    k = vr / (2.0 * prm.max_h_decel_mps2)
    length = _hypot(n1 - n, e1 - e) + vr * k
    return new_record(_DemandPath, (n, e, n1, e1, n1 + rn * k, e1 + re_ * k, length, a * tr / 8.0))


def _check_demand(
    fence: Fence,
    n: float,
    e: float,
    h: float,
    vd: float,
    demand_up: float,
    sigma_v_m: float,
    airborne: bool,
    w: float,
    path: _DemandPath,
) -> FenceResult:
    """:func:`check` for a multirotor whose command demands more speed: the two-segment path horizontally,
    the reaction-time climb (or sink) towards the demanded vertical speed vertically."""
    prm = fence.params
    tr = prm.reaction_time_s
    d, sag = path.length_m, path.sag_m
    reach = d
    trip_h = False
    if fence._forbidden is not None:
        lb = _lower_bound(fence, n, e)
        if not (lb > reach + w + sag):
            if _outside_box(fence, n, e):
                trip_h = True
            elif fence._grid_nj and (
                _segment_clear(fence, path.n1, path.e1, path.n2, path.e2, w + sag, _GRID_DEPTH)
                and _segment_clear(fence, path.n0, path.e0, path.n1, path.e1, w + sag, _GRID_DEPTH)
            ):
                trip_h = False
            else:
                hazard = _local_hazard(fence, n, e, reach + w + sag)
                trip_h = hazard is not _NOTHING_NEAR and bool(
                    shapely.dwithin(hazard, shapely.linestrings(_demand_verts(path)), w + sag)
                )
    ceiling, floor = prm.altitude_ceiling_m, prm.altitude_floor_m
    wv = prm.margin_m + prm.sigma_k * sigma_v_m
    av = prm.max_v_accel_mps2 * tr
    trip_c = trip_f = False
    dv_up = dv_down = 0.0
    if ceiling is not None:
        up = -vd if vd < 0.0 else 0.0
        up_r = up + min(max(demand_up - up, 0.0), av)
        dv_up = 0.5 * (up + up_r) * tr + up_r * up_r / (2.0 * prm.max_v_decel_mps2)
        trip_c = h + dv_up + wv >= ceiling
    if airborne and floor is not None:
        down = vd if vd > 0.0 else 0.0
        down_r = down + min(max(-demand_up - down, 0.0), av)
        dv_down = 0.5 * (down + down_r) * tr + down_r * down_r / (2.0 * prm.max_v_decel_mps2)
        trip_f = h - dv_down - wv <= floor
    if not (trip_h or trip_c or trip_f):
        return FenceResult(False, "", d, _NAN)
    if trip_h and not _inside(fence, n, e):
        return FenceResult(True, "outside", d, _signed_h(fence, n, e) - w)
    if trip_c:
        assert ceiling is not None
        return FenceResult(True, "ceiling", dv_up, ceiling - h - wv)
    if trip_f:
        assert floor is not None
        return FenceResult(True, "floor", dv_down, h - floor - wv)
    with np.errstate(all="ignore"):
        kind, clearance = _projected_clearance(
            fence, n, e, 0.0, 0.0, d, d, None, w + sag, 0.0, reach, _NO_WIND, _demand_verts(path)
        )
    return FenceResult(True, kind, d, clearance)


def _lower_bound(fence: Fence, n: float, e: float) -> float:
    """A lower bound of the distance from (n, e) to the forbidden area; -inf when unknown or outside."""
    n0, e0, n1, e1 = fence._box
    if n0 <= n < n1 and e0 <= e < e1:
        nj = fence._grid_nj
        if nj == 0:
            return -_INF
        inv = fence._grid_inv_cell
        i = int((n - n0) * inv)
        j = int((e - e0) * inv)
        if i >= fence._grid_ni:
            i = fence._grid_ni - 1
        if j >= nj:
            j = nj - 1
        g = fence._grid[i * nj + j]
        if g == -_INF:
            return g
        cell = fence._grid_cell
        return g - _hypot(n - (n0 + (i + 0.5) * cell), e - (e0 + (j + 0.5) * cell))
    if fence._has_inclusion:
        return -_INF  # beyond the box around the inclusion zones: outside
    # Exclusions only: they all lie inside the box, so the distance to the box bounds the distance to them.
    dn = n0 - n if n < n0 else (n - n1 if n > n1 else 0.0)
    de = e0 - e if e < e0 else (e - e1 if e > e1 else 0.0)
    return _hypot(dn, de)


_GRID_DEPTH: Final = 4  # a path piece is split in halves at most this many times in the grid pre-check


def _grid_clears_path(
    fence: Fence,
    n: float,
    e: float,
    vn: float,
    ve: float,
    v: float,
    d: float,
    leg: float,
    radius: float,
    w: float,
    fixed_wing: bool,
    drift_m: float = 0.0,
    turn: FixedWingTurn | None = None,
) -> bool:
    """True when the distance field alone proves that the exact test would find the path clear.

    ``drift_m`` (fixed wing in wind): every point of the drifted path is within the whole manoeuvre's drift
    of the air path's point, so the air path is tested with the widening grown by it (cautious).

    A piece of path lies within a disc (a segment: about its midpoint, radius half its length; an arc:
    about its middle point, radius half its length; the half turn: about the turn centre, radius R);
    when the field's lower bound at the disc's centre exceeds its radius plus the widening, that piece is
    clear; otherwise it is halved, up to ``_GRID_DEPTH`` times. For a fixed wing one clear turn suffices;
    the exact test's polyline may lie a chord error off the arc and its widening adds that error, hence
    twice the sag here. A roll-out (``turn`` given, :func:`fixed_wing_turn`) is tested as the disc of its
    arc's length about the position, and the leg and the turn from the arc's end on its heading. Pure
    Python: no shapely call.
    """
    if not (v > 0.0):
        return _lower_bound(fence, n, e) > w
    un, ue = vn / v, ve / v
    if not fixed_wing:
        return _segment_clear(fence, n, e, n + d * un, e + d * ue, w, _GRID_DEPTH)
    need = w + 2.0 * _WIND_SAG_FACTOR * max(_arc_table(fence, radius)[0], ARC_CHORD_ERROR_M) + drift_m
    for side in (1.0, -1.0):
        sn_, se_, su_n, su_e, side_leg = n, e, un, ue, leg
        if turn is not None and turn.rolls_out(side):
            arc = turn.rollout_radius_m * turn.rollout_turn_rad
            if not (_lower_bound(fence, n, e) > arc + need):
                continue
            head, _t, _sag = _rollout_arc(n, e, un, ue, turn, side)
            sn_, se_ = float(head[-1, 0]), float(head[-1, 1])
            su_n, su_e = _rolled_out_heading(un, ue, turn, side)
            side_leg = leg + 0.5 * turn.rollout_m()
        an, ae = sn_ + side_leg * su_n, se_ + side_leg * su_e
        rn, re_ = -su_e * side, su_n * side
        centre_clear = _lower_bound(fence, an + radius * rn, ae + radius * re_) > radius + need
        if turn is not None and turn.inner_radius_m > 0.0:
            # The area between the inner edge (the half turn of radius r <= R from the leg's start) and this
            # path (leg L, then R) is swept by the paths of leg lam L and radius r + lam (R - r), lam in
            # [0, 1]; at each angle of the turn their points lie on one segment, so every point of the area
            # is within d = hypot(L / 2, D) + D of the middle path (leg L / 2, radius r + D, D = (R - r) / 2),
            # whose leg and turn are tested with the widening grown by d. The area's far corner (_far_corner)
            # closes it over the rectangle of those paths' ends, within hypot(L / 2, 2 D) <= d of the middle
            # path's end.
            half_d = 0.5 * (radius - turn.inner_radius_m)
            spread = _hypot(0.5 * side_leg, half_d) + half_d
            mid_r, mid_leg = turn.inner_radius_m + half_d, 0.5 * side_leg
            mn, me = sn_ + mid_leg * su_n, se_ + mid_leg * su_e
            wider = need + spread
            if (
                _lower_bound(fence, mn + mid_r * rn, me + mid_r * re_) > mid_r + wider
                or _arc_clear(fence, mn, me, su_n, su_e, rn, re_, mid_r, 0.0, math.pi, wider, _GRID_DEPTH)
            ) and (mid_leg <= 0.0 or _segment_clear(fence, sn_, se_, mn, me, wider, _GRID_DEPTH)):
                return True
            continue
        if (
            centre_clear
            or _arc_clear(fence, an, ae, su_n, su_e, rn, re_, radius, 0.0, math.pi, need, _GRID_DEPTH)
        ) and (side_leg <= 0.0 or _segment_clear(fence, sn_, se_, an, ae, need, _GRID_DEPTH)):
            return True
    return False


def _segment_clear(fence: Fence, an: float, ae: float, bn: float, be: float, need: float, depth: int) -> bool:
    mn, me = 0.5 * (an + bn), 0.5 * (ae + be)
    half = 0.5 * _hypot(bn - an, be - ae)
    if _lower_bound(fence, mn, me) > need + half:
        return True
    if depth <= 0:
        return False
    # the far half first: it is the likelier to fail
    return _segment_clear(fence, mn, me, bn, be, need, depth - 1) and _segment_clear(
        fence, an, ae, mn, me, need, depth - 1
    )


def _arc_clear(
    fence: Fence,
    an: float,
    ae: float,
    un: float,
    ue: float,
    rn: float,
    re_: float,
    radius: float,
    phi0: float,
    phi1: float,
    need: float,
    depth: int,
) -> bool:
    pm = 0.5 * (phi0 + phi1)
    c, sn = 1.0 - math.cos(pm), math.sin(pm)
    half = 0.5 * radius * (phi1 - phi0)  # half the arc length bounds the distance to its middle point
    if _lower_bound(fence, an + radius * (rn * c + un * sn), ae + radius * (re_ * c + ue * sn)) > need + half:
        return True
    if depth <= 0:
        return False
    return _arc_clear(fence, an, ae, un, ue, rn, re_, radius, pm, phi1, need, depth - 1) and _arc_clear(
        fence, an, ae, un, ue, rn, re_, radius, phi0, pm, need, depth - 1
    )


def _outside_box(fence: Fence, n: float, e: float) -> bool:
    """Beyond the box around the inclusion zones (certainly outside the fence)."""
    if not fence._has_inclusion:
        return False
    n0, e0, n1, e1 = fence._box
    return not (n0 <= n < n1 and e0 <= e < e1)


def _inside(fence: Fence, n: float, e: float) -> bool:
    """Strictly inside the allowed area (a point on a boundary is outside)."""
    if fence._has_inclusion:
        return bool(shapely.contains_xy(fence._allowed, n, e))
    if fence._forbidden is None:
        return True
    return not bool(shapely.intersects_xy(fence._forbidden, n, e))


def _signed_h(fence: Fence, n: float, e: float) -> float:
    """Horizontal distance to the nearest hazard boundary: positive inside, negative outside."""
    if fence._forbidden is None:
        return _INF
    pt = shapely.points((n, e))
    if _inside(fence, n, e):
        return float(shapely.distance(fence._forbidden, pt))
    if fence._has_inclusion:
        return -float(shapely.distance(fence._allowed, pt))
    return -float(shapely.distance(fence._excl_boundary, pt))


def _arc_table(fence: Fence, radius: float) -> tuple[float, FloatArray, FloatArray]:
    """Cosines and sines of the half-turn's polyline, and its chord error (sagitta) for this radius."""
    for _m, sag_per_r, c, s in fence._arc_tables:
        if sag_per_r * radius <= ARC_CHORD_ERROR_M:
            return sag_per_r * radius, c, s
    _m, sag_per_r, c, s = fence._arc_tables[-1]
    return sag_per_r * radius, c, s


#: The polyline of a drifting turn (a trochoid) is never farther from the true path than the air arc's
#: chord error times this factor: between two vertices the drift is linear in time, so it cancels in the
#: time-linear interpolation, and what remains is the circular motion's deviation from its chord taken at
#: equal times, at most R (1 - cos a) in the chord's normal plus R (sin t - t sin(a)/a) along it for a
#: half-angle a; the second is below 2.6 % of the first for the coarsest table (a = pi/16), so 1.05 holds.
_WIND_SAG_FACTOR: Final = 1.05
_NO_WIND: tuple[float, float] = (0.0, 0.0)


#: The largest bank the roll-out counts: a coordinated level turn beyond it needs more than 5.7 g, which no
#: wing lifts in a fixed wing's speed range; an aircraft banked further turns no faster than this.
_ROLLOUT_BANK_MAX_RAD: Final = _radians(80.0)
#: A bank smaller than this is level for the roll-out: it would turn the heading by under a nanoradian, and a
#: subnormal one made the roll-out's radius overflow (infinite, the path NaN), which the distance tests read as
#: clear (tests/core/test_geofence_fixedwing_inner_edge.py).
_MIN_ROLLOUT_BANK_RAD: Final = 1.0e-9


class FixedWingTurn(NamedTuple):
    """The fixed-wing escape as the trusted loops fly it, in the air mass (:func:`fixed_wing_turn`).

    A straight leg of ``leg_m``: the reaction time at the airspeed ``v0_mps`` of the trip, then, when the
    aircraft is slower than the loops' full-bank airspeed, the speed regained wings level, for
    ``accel_s`` (the speed loop's first-order approach to ``v_turn_mps``). Then the half turn of
    ``radius_m`` at the bank limit, flown at ``v_turn_mps``. ``duration_s``: the whole manoeuvre's time
    (what the wind drifts it by), the roll-out included.

    ``bank_rad`` (right positive): the bank at the trip. A turn to the other side first rolls it out, for
    ``rollout_s`` (the bank over the loops' roll rate); the path counts the bank held for the first half of
    that time (``rollout_turn_rad`` of heading towards the bank, on an arc of ``rollout_radius_m``), then
    straight for the second half, before the reaction leg: the bank only decreases while it is rolled out
    and the turn rate ``g tan(bank) / V`` is convex in the bank, so that heading leads the real one at
    every moment (scenarios ``fw_adv_pullup_reversal_tailwind`` and ``fw_adv_dive_reversal``).

    ``inner_radius_m`` (0: none): the radius of the side's inner edge, the half turn begun at once (after the
    roll-out's arc, if any) at the steepest bank the loops fly, at ``inner_speed_mps``: the slower of ``v0_mps``
    and the loops' full-bank airspeed (:func:`fixed_wing_turn`)."""

    v0_mps: float
    reaction_s: float
    accel_s: float
    v_turn_mps: float
    speed_gain_per_s: float
    leg_m: float
    radius_m: float
    duration_s: float
    bank_rad: float = 0.0
    rollout_s: float = 0.0
    rollout_turn_rad: float = 0.0
    rollout_radius_m: float = 0.0
    inner_radius_m: float = 0.0
    inner_speed_mps: float = 0.0

    def leg_s_m(self, t: FloatArray) -> FloatArray:
        """Distance along the leg at the times ``t`` (0..reaction_s + accel_s)."""
        tr, v0, k, ve = self.reaction_s, self.v0_mps, self.speed_gain_per_s, self.v_turn_mps
        ta = np.clip(t - tr, 0.0, None)
        return np.asarray(v0 * np.minimum(t, tr) + ve * ta - (ve - v0) * (1.0 - np.exp(-k * ta)) / k)

    def rolls_out(self, side: float) -> bool:
        """Whether the turn to ``side`` (+1 right, -1 left) first rolls out a bank towards the other side."""
        return self.rollout_s > 0.0 and self.bank_rad * side < 0.0

    def rollout_m(self) -> float:
        """The roll-out's path length (0 when none is flown to either side)."""
        return self.v0_mps * self.rollout_s


def fixed_wing_turn(prm: FenceParams, v_air_mps: float, bank_rad: float = 0.0) -> FixedWingTurn:
    """The escape the projection assumes from airspeed ``v_air_mps`` and bank ``bank_rad``, in the model the
    trusted loops fly (:mod:`merlin.autopilot.fixedwing_control`, whose parameters set
    ``full_bank_airspeed_mps``, ``turn_airspeed_mps``, ``turn_speed_gain_per_s`` and ``roll_rate_radps``
    through :func:`merlin.config.fence_build`):

    * a bank towards the other side is rolled out first, at the loops' roll rate (:class:`FixedWingTurn`);
    * the reaction time at the current airspeed (detection, roll-in);
    * below the full-bank airspeed ``V_b`` the loops give the bank only in part (and none while they
      recover from a stall), so the turn waits for the speed: the speed loop approaches its target ``V_t``
      as ``V_t - (V_t - v) exp(-k t)``, which reaches ``V_b`` after ``ln((V_t - v) / (V_t - V_b)) / k``
      over ``V_t t - (V_t - v)(1 - exp(-k t)) / k`` (flown straight: the partial bank on the way only
      turns the aircraft earlier, away from the hazard the turn escapes);
    * the half turn at the bank limit at ``max(v, V_t)``: the radius ``V^2 / (g tan(bank))`` and the time
      ``pi V / (g tan(bank))`` both grow with the speed, so the faster speed the loops may fly it at is
      the cautious one (the loops slow a faster aircraft to ``V_t`` in the turn);
    * that path is the outer edge of the side's swept area. Its inner edge (``turn_bank_max_rad`` > 0) is the
      half turn begun at once at the steepest bank the loops fly (their own bank limit, or the bank held now if
      steeper), radius ``V^2 / (g tan(bank))`` at ``V`` the slower of the current airspeed and the full-bank
      airspeed: an aircraft already banked towards the side keeps turning through the reaction time, the
      loops bank beyond the projection's ``bank_limit_rad``, and a faster aircraft slows to the escape
      airspeed in the turn, its radius shrinking with the speed (a turn begun at 33 m/s ends some 90 m inside
      the circle of its starting radius), down to the full-bank airspeed's, below which the loops level the
      wings; so the flown turn lies between the edges. A hazard on the inside of the turn (a
      keep-out the turn wraps round) meets the inner edge first; the side is clear only when the area between
      the edges is (:func:`_boundary`, :func:`_encloses`). Scenario ``fw_adv_mast_inside_banked_turn``: an RTL turning
      right round the radio mast in a tailwind, whose projected right turn (straight for the reaction time,
      then at 30 deg) passed the mast where the flown one, banked 29-39 deg and turning from the start, entered it by
      18.8 m.

    Scenarios ``fw_adv_slow_pullup_west_wind`` and ``fw_adv_slow_climb_notch`` pin it: a slow aircraft
    revoked where the turn at its current airspeed would have cleared the edge, whose real turn started
    seconds later and wider and left the range."""
    v = max(v_air_mps, 0.0)
    tr = prm.reaction_time_s
    g_tan = prm.gravity_mps2 * math.tan(prm.bank_limit_rad)
    k = prm.turn_speed_gain_per_s
    vt = max(v, prm.turn_airspeed_mps)
    accel_s = 0.0
    if v < prm.full_bank_airspeed_mps:
        accel_s = math.log((vt - v) / (vt - prm.full_bank_airspeed_mps)) / k
    leg = v * tr + vt * accel_s - (vt - v) * (1.0 - math.exp(-k * accel_s)) / k
    radius = vt * vt / g_tan
    phi = min(abs(bank_rad), _ROLLOUT_BANK_MAX_RAD) if _isfinite(bank_rad) else _ROLLOUT_BANK_MAX_RAD
    rollout_s = rollout_turn = rollout_radius = 0.0
    if not (phi >= _MIN_ROLLOUT_BANK_RAD):
        phi = 0.0
    if prm.roll_rate_radps > 0.0 and phi > 0.0 and v > 0.0:
        rollout_s = phi / prm.roll_rate_radps
        rate = prm.gravity_mps2 * math.tan(phi) / v
        rollout_turn, rollout_radius = 0.5 * rollout_s * rate, v / rate
    inner = inner_v = 0.0
    if prm.turn_bank_max_rad > 0.0 and v > 0.0:
        steepest = max(prm.turn_bank_max_rad, prm.bank_limit_rad, phi)
        # the tightest radius at any speed the turn may slow to, whatever the rate of slowing
        inner_v = min(v, prm.full_bank_airspeed_mps) if prm.full_bank_airspeed_mps > 0.0 else v
        inner = inner_v * inner_v / (prm.gravity_mps2 * math.tan(steepest))
    return new_record(FixedWingTurn, (v, tr, accel_s, vt, k, leg, radius,
                                      rollout_s + tr + accel_s + math.pi * vt / g_tan,
                                      math.copysign(phi, bank_rad) if phi > 0.0 else 0.0, rollout_s, rollout_turn,
                                      rollout_radius, inner, inner_v))


#: Time samples of a leg that regains speed in a wind (its ground path is curved: the air path's distance
#: is not linear in time while the drift is); the chord error between samples is added to the widening.
_LEG_SAMPLES: Final = 8


def _escape_speed_mps(v_h_mps: float, vd_mps: float) -> float:
    """The airspeed the escape is projected at from horizontal air speed ``v_h_mps`` and vertical speed
    ``vd_mps``: the whole airspeed (no vertical wind), which the loops keep when they level a dive or a climb.
    A vehicle with no horizontal speed has no direction to project: its horizontal speed (0) as before."""
    return _hypot(v_h_mps, vd_mps) if v_h_mps > 0.0 else v_h_mps


def _leg_sag_m(turn: FixedWingTurn) -> float:
    """The largest chord error of a sampled speed-regaining leg (:func:`_turn_path`); 0 when none is flown."""
    if not (turn.accel_s > 0.0):
        return 0.0
    dt = turn.accel_s / _LEG_SAMPLES
    return (turn.v_turn_mps - turn.v0_mps) * turn.speed_gain_per_s * dt * dt / 8.0


def _drift_m(wind: tuple[float, float], turn: FixedWingTurn) -> float:
    """How far the wind carries a fixed wing over the reaction leg and the half turn (0 without wind)."""
    if wind is _NO_WIND or not (turn.v_turn_mps > 0.0):
        return 0.0
    return _hypot(wind[0], wind[1]) * turn.duration_s


def _turn_path(
    fence: Fence,
    n: float,
    e: float,
    un: float,
    ue: float,
    turn: FixedWingTurn,
    side: float,
    wind: tuple[float, float] = _NO_WIND,
) -> tuple[FloatArray, float]:
    """The fixed-wing path: the roll-out of a bank towards the other side (if any), the straight leg, then a
    half turn (side +1 right, -1 left). Returns (verts, sag).

    ``un, ue`` is the direction of the air velocity. With a ``wind``, each vertex is moved downwind by
    ``wind * t``, ``t`` being when the aircraft flying the air path (:class:`FixedWingTurn`) reaches it:
    the ground path of a constant-bank turn in a steady wind. A leg that regains speed is sampled in time
    (its ground path bends), and its chord error is added to the returned sag."""
    drifting = wind is not _NO_WIND and turn.v_turn_mps > 0.0
    if not turn.rolls_out(side):
        verts, t, sag = _air_path(fence, n, e, un, ue, turn, side, drifting)
    else:
        head, t_head, sag_out = _rollout_arc(n, e, un, ue, turn, side)
        # the rest of the roll-out, straight: a longer reaction leg from the arc's end, on the new heading
        half = 0.5 * turn.rollout_s
        rest = turn._replace(reaction_s=turn.reaction_s + half, leg_m=turn.leg_m + turn.v0_mps * half)
        un2, ue2 = _rolled_out_heading(un, ue, turn, side)
        tail, t_tail, sag = _air_path(fence, float(head[-1, 0]), float(head[-1, 1]), un2, ue2, rest, side, drifting)
        verts = np.vstack((head[:-1], tail))
        t = np.concatenate((t_head[:-1], t_tail + half))
        sag = max(sag, sag_out * _WIND_SAG_FACTOR if drifting else sag_out)
    if drifting:
        verts[:, 0] += wind[0] * t
        verts[:, 1] += wind[1] * t
    return verts, sag


def _inner_path(
    fence: Fence,
    n: float,
    e: float,
    un: float,
    ue: float,
    turn: FixedWingTurn,
    side: float,
    wind: tuple[float, float] = _NO_WIND,
) -> tuple[FloatArray, float, int]:
    """The inner edge of the side's swept area (:func:`fixed_wing_turn`): the roll-out's arc, if the turn
    rolls one out, then at once the half turn of ``turn.inner_radius_m`` flown at ``turn.inner_speed_mps``,
    drifted by the wind as :func:`_turn_path` drifts the outer edge. Returns (verts, sag, shared): ``shared``, how many
    leading vertices are the outer edge's own (the roll-out's arc but its end), 0 without a roll-out."""
    drifting = wind is not _NO_WIND and turn.v0_mps > 0.0
    r = turn.inner_radius_m
    sag, cphi, sphi = _arc_table(fence, r)
    sn_, se_, t0 = n, e, 0.0
    head: FloatArray | None = None
    t_head: FloatArray | None = None
    if turn.rolls_out(side):
        head, t_head, sag_out = _rollout_arc(n, e, un, ue, turn, side)
        sn_, se_, t0 = float(head[-1, 0]), float(head[-1, 1]), float(t_head[-1])
        un, ue = _rolled_out_heading(un, ue, turn, side)
        sag = max(sag, sag_out)
    rn, re_ = -ue * side, un * side  # unit normal towards the turn centre
    arc = np.empty((cphi.shape[0], 2))
    arc[:, 0] = sn_ + r * (rn - rn * cphi + un * sphi)
    arc[:, 1] = se_ + r * (re_ - re_ * cphi + ue * sphi)
    shared = 0
    if head is not None and t_head is not None:
        verts = np.vstack((head[:-1], arc))
        t = np.concatenate((t_head[:-1], t0 + r * np.arctan2(sphi, cphi) / turn.inner_speed_mps))
        shared = head.shape[0] - 1
    else:
        verts = arc
        t = r * np.arctan2(sphi, cphi) / turn.inner_speed_mps
    if drifting:
        verts[:, 0] += wind[0] * t
        verts[:, 1] += wind[1] * t
        sag *= _WIND_SAG_FACTOR
    return verts, sag, shared


def _encloses(fence: Fence, n: float, e: float, reach: float, outer: FloatArray, corner: FloatArray,
              inner: FloatArray, shared: int) -> bool:
    """Whether a bounded part of the forbidden area (``Fence._enclosed``: a keep-out inside the range) lies in
    the area between a side's two edges (:func:`fixed_wing_turn`). Asked once the line round the area keeps
    clear: then only such a part can meet the area, whole and inside it, and every turn the loops may fly
    between the edges crosses it (a keep-out small enough to lie between them). The area is built only when
    one lies within ``reach`` of the position: the bound on how far either edge's vertices lie from it
    (:func:`check`'s and :func:`turn_clearances`' reach), so on the area too, the hull of those vertices. A
    keep-out that meets the area and not the line round it lies inside it, at least the widening nearer
    than that."""
    enclosed = fence._enclosed
    if enclosed is None or not bool(shapely.dwithin(enclosed, shapely.points((n, e)), reach)):
        return False
    return bool(shapely.intersects(enclosed, _area(outer, corner, inner, shared)))


def _far_corner(outer: FloatArray, turn: FixedWingTurn, un: float, ue: float, side: float,
                wind: tuple[float, float]) -> FloatArray:
    """Where a side's area closes beyond the half turns' ends (:func:`fixed_wing_turn`): the end of the outer
    edge's half turn had it begun at once, with no leg. The turns between the edges (a leg from 0 to the
    outer's, a radius from the inner's to the outer's) end their half turns at the leg's length along the
    heading from the line through the aircraft, at twice their radius across it: in the rectangle whose
    corners are the two edges' ends and this point. A segment straight from one end to the other cut off half
    of it, where a turn begun at once at a radius between the two ends its half turn (a keep-out there was
    missed: ``tests/core/test_geofence_fixedwing_inner_edge.py``, the slowing turns beside a wall). In the wind
    it drifts as that turn would, the leg's time sooner than the outer's end."""
    leg, t_leg = turn.leg_m, turn.reaction_s + turn.accel_s
    hn, he = un, ue
    if turn.rolls_out(side):
        half = 0.5 * turn.rollout_s
        leg, t_leg = leg + turn.v0_mps * half, t_leg + half
        hn, he = _rolled_out_heading(un, ue, turn, side)
    corner = np.array((float(outer[-1, 0]) - leg * hn, float(outer[-1, 1]) - leg * he))
    if wind is not _NO_WIND and turn.v_turn_mps > 0.0:
        corner[0] -= wind[0] * t_leg
        corner[1] -= wind[1] * t_leg
    return corner


def _boundary(outer: FloatArray, corner: FloatArray, inner: FloatArray, shared: int) -> FloatArray:
    """The polyline round a side's area (:func:`fixed_wing_turn`): the outer edge, its far corner
    (:func:`_far_corner`), then back along the inner one to the end of their shared roll-out arc."""
    return np.vstack((outer, corner[None, :], inner[shared:][::-1]))


def _area(outer: FloatArray, corner: FloatArray, inner: FloatArray, shared: int) -> Any:
    """The area between a side's two edges, from the end of their shared roll-out arc (the aircraft's position
    without one): the outer edge, its far corner, then the inner one back, closes it. A ring whose edges cross
    (the wind drifts them by different times) is made valid: the same points, as polygons and lines."""
    area = shapely.polygons(np.vstack((outer[shared:], corner[None, :], inner[shared:][::-1])))
    if not shapely.is_valid(area):
        area = shapely.make_valid(area)
    return area


def _rolled_out_heading(un: float, ue: float, turn: FixedWingTurn, side: float) -> tuple[float, float]:
    """The unit heading at the end of the roll-out's arc (:func:`_rollout_arc`) before a turn to ``side``: the
    heading ``un, ue`` turned by ``turn.rollout_turn_rad`` towards the bank (-side); a right bank turns it
    clockwise (north towards east). One expression for every path that starts from the arc's end, so that
    they all start on the same bits."""
    c, sn = math.cos(turn.rollout_turn_rad), math.sin(turn.rollout_turn_rad)
    return c * un + side * sn * ue, c * ue - side * sn * un


#: The roll-out arc's polyline is within this of the arc (as the half turn's, :data:`ARC_CHORD_ERROR_M`).
_ROLLOUT_MAX_SEGMENTS: Final = 64


def _rollout_arc(n: float, e: float, un: float, ue: float, turn: FixedWingTurn,
                 side: float) -> tuple[FloatArray, FloatArray, float]:
    """The first half of a roll-out before a turn to ``side``: the arc flown at the bank of the trip (towards
    -side), as a polyline with its vertex times and chord error."""
    r, ang = turn.rollout_radius_m, turn.rollout_turn_rad
    # segments so that the chord error r (1 - cos(da / 2)) stays within ARC_CHORD_ERROR_M
    m = 1
    if r * (1.0 - math.cos(0.5 * ang)) > ARC_CHORD_ERROR_M:
        da_max = 2.0 * _acos(max(1.0 - ARC_CHORD_ERROR_M / r, -1.0))
        m = min(max(math.ceil(ang / da_max), 1), _ROLLOUT_MAX_SEGMENTS)
    phi = np.linspace(0.0, ang, m + 1)
    rn, re_ = ue * side, -un * side  # unit normal towards the roll-out's centre (the bank's side, -side)
    one_c, sn = 1.0 - np.cos(phi), np.sin(phi)
    verts = np.empty((m + 1, 2))
    verts[:, 0] = n + r * (rn * one_c + un * sn)
    verts[:, 1] = e + r * (re_ * one_c + ue * sn)
    sag = r * (1.0 - math.cos(0.5 * ang / m))
    return verts, phi * r / turn.v0_mps, sag


def _air_path(
    fence: Fence,
    n: float,
    e: float,
    un: float,
    ue: float,
    turn: FixedWingTurn,
    side: float,
    timed: bool,
) -> tuple[FloatArray, FloatArray, float]:
    """The straight leg and the half turn in the air mass, from (n, e) on ``un, ue``: (verts, times, sag).
    The times are filled in only when ``timed`` (a wind drifts the path by them)."""
    leg, radius = turn.leg_m, turn.radius_m
    sag, cphi, sphi = _arc_table(fence, radius)
    an, ae = n + leg * un, e + leg * ue  # start of the turn
    rn, re_ = -ue * side, un * side  # unit normal towards the turn centre (right of u for side = +1)
    lead = _LEG_SAMPLES + 1 if timed and turn.accel_s > 0.0 else 1
    verts = np.empty((cphi.shape[0] + lead, 2))
    t = np.zeros(verts.shape[0])
    verts[0, 0], verts[0, 1] = n, e
    if lead > 1:
        # the end of the reaction leg, then the speed regained, in equal steps of time
        tl = turn.reaction_s + turn.accel_s * np.arange(0, _LEG_SAMPLES) / _LEG_SAMPLES
        sl = turn.leg_s_m(tl)
        verts[1:lead, 0] = n + sl * un
        verts[1:lead, 1] = e + sl * ue
        t[1:lead] = tl
        # |d2s/dt2| <= (V_t - v) k; a chord over dt is within max|p''| dt^2 / 8 of the curve
        leg_sag = _leg_sag_m(turn)
    else:
        leg_sag = 0.0
    # point(phi) = centre + R (-normal cos(phi) + u sin(phi)): phi = 0 is the turn's start, heading u.
    verts[lead:, 0] = an + radius * (rn - rn * cphi + un * sphi)
    verts[lead:, 1] = ae + radius * (re_ - re_ * cphi + ue * sphi)
    if timed:
        # the tables hold phi = linspace(0, pi, m + 1); arctan2 gives it back exactly enough for a time
        t[lead:] = turn.reaction_s + turn.accel_s + radius * np.arctan2(sphi, cphi) / turn.v_turn_mps
        sag = sag * _WIND_SAG_FACTOR + leg_sag
    return verts, t, sag


def _path_hits(
    fence: Fence,
    n: float,
    e: float,
    vn: float,
    ve: float,
    v: float,
    d: float,
    turn: FixedWingTurn | None,
    w: float,
    sag: float,
    reach: float,
    wind: tuple[float, float] = _NO_WIND,
) -> bool:
    """The exact test: does the projected path (either turn, for a fixed wing: ``turn`` given) come within w
    of a hazard."""
    hazard = _local_hazard(fence, n, e, reach + w + sag)
    if hazard is _NOTHING_NEAR:
        return False
    if reach < _MIN_PATH_M:
        # At rest, or nearly: GEOS's prepared dwithin misses a zero-length line and divides by the squared
        # length of a tiny one, so the path is tested as its start point with the widening grown by its
        # reach (cautious by at most a micrometre).
        return bool(shapely.dwithin(hazard, shapely.points((n, e)), w + reach))
    if turn is None:
        k = d / v
        path = shapely.linestrings(np.array(((n, e), (n + k * vn, e + k * ve))))
        return bool(shapely.dwithin(hazard, path, w))
    un, ue = vn / v, ve / v
    for side in (1.0, -1.0):
        verts, arc_sag = _turn_path(fence, n, e, un, ue, turn, side, wind)
        if bool(shapely.dwithin(hazard, shapely.linestrings(verts), w + arc_sag)):
            continue  # the projection's turn is blocked
        if turn.inner_radius_m > 0.0:
            # the side's area: the line round it (a line is cheaper than the area), then a keep-out inside it
            inner, inner_sag, shared = _inner_path(fence, n, e, un, ue, turn, side, wind)
            corner = _far_corner(verts, turn, un, ue, side, wind)
            side_w = w + max(arc_sag, inner_sag)
            if bool(shapely.dwithin(hazard, shapely.linestrings(_boundary(verts, corner, inner, shared)), side_w)):
                continue
            if _encloses(fence, n, e, reach, verts, corner, inner, shared):
                continue
        return False  # this turn stays clear: no trip
    return True


def _first_hit_s(geom: Any, verts: FloatArray, w: float) -> float:
    """Arc length along the polyline ``verts`` at which it first comes within ``w`` of ``geom``.

    inf when it never does; ``distance - w`` (<= 0) when its start already is. Sphere tracing first: from
    a path point at distance ``r`` from ``geom``, the next ``r - w`` metres of path (arc length bounds the
    straight-line distance) cannot come within ``w``, so stepping by that is safe and converges on the
    first contact in a few steps unless the path grazes the band; then bisection on prefixes of the path.
    Reports the longest prefix known clear (never more than the true value), within 1 cm.
    """
    start = shapely.points(verts[0])
    r0 = float(shapely.distance(geom, start))
    if r0 <= w:
        return r0 - w
    seg = np.hypot(np.diff(verts[:, 0]), np.diff(verts[:, 1]))
    cum = np.concatenate(([0.0], np.cumsum(seg)))
    total = float(cum[-1])
    if total < _MIN_PATH_M:
        return total if r0 <= w + total else _INF
    tol = max(_CLEARANCE_RESOLUTION_M, 1e-6 * total)
    lo, r = 0.0, r0
    for _ in range(_TRACE_STEPS):
        step = r - w
        if step <= 0.5 * tol:
            break
        lo += step
        if lo >= total:
            return _INF  # the whole path is covered by clear balls
        pn, pe = _point_at(verts, cum, lo)
        r = float(shapely.distance(geom, shapely.points((pn, pe))))
    if (
        r - w <= 0.5 * tol
        and lo + tol < total
        and bool(shapely.dwithin(geom, shapely.linestrings(_prefix(verts, cum, lo + tol)), w))
    ):
        return lo  # contact within tol of the traced point
    hi = total
    if not bool(shapely.dwithin(geom, shapely.linestrings(verts), w)):
        return _INF
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if bool(shapely.dwithin(geom, shapely.linestrings(_prefix(verts, cum, mid)), w)):
            hi = mid
        else:
            lo = mid
    return lo


def _point_at(verts: FloatArray, cum: FloatArray, s: float) -> tuple[float, float]:
    if cum.shape[0] == 2:  # a segment: no search
        t = s / float(cum[1])
        return (
            float(verts[0, 0] + t * (verts[1, 0] - verts[0, 0])),
            float(verts[0, 1] + t * (verts[1, 1] - verts[0, 1])),
        )
    k = min(max(int(np.searchsorted(cum, s, side="right")), 1), cum.shape[0] - 1)
    span = float(cum[k] - cum[k - 1])
    t = (s - float(cum[k - 1])) / span if span > 0.0 else 0.0
    return (
        float(verts[k - 1, 0] + t * (verts[k, 0] - verts[k - 1, 0])),
        float(verts[k - 1, 1] + t * (verts[k, 1] - verts[k - 1, 1])),
    )


def _prefix(verts: FloatArray, cum: FloatArray, s: float) -> FloatArray:
    k = int(np.searchsorted(cum, s, side="right"))
    if k >= cum.shape[0]:
        return verts
    k = max(k, 1)
    span = float(cum[k] - cum[k - 1])
    t = (s - float(cum[k - 1])) / span if span > 0.0 else 0.0
    end = verts[k - 1] + t * (verts[k] - verts[k - 1])
    return np.vstack((verts[:k], end[None, :]))


def _projected_clearance(
    fence: Fence,
    n: float,
    e: float,
    vn: float,
    ve: float,
    v: float,
    d: float,
    turn: FixedWingTurn | None,
    w: float,
    sag: float,
    reach: float,
    wind: tuple[float, float] = _NO_WIND,
    path_verts: FloatArray | None = None,
) -> tuple[FenceKind, float]:
    """Which hazard limits the projected path and how much path is available before it (the limit).

    ``path_verts``: a multirotor path given as a polyline (:func:`_demanded_path`) instead of the segment."""
    # each side's paths: a fixed wing's turn, and its inner edge when it has one (the side is met where the
    # first of them is)
    sides: list[list[tuple[FloatArray, float]]]
    if path_verts is not None:
        sides = [[(path_verts, 0.0)]]
    elif turn is not None:
        un, ue = (vn / v, ve / v) if v > 0.0 else (1.0, 0.0)
        sides = []
        for side in (1.0, -1.0):
            verts, arc_sag = _turn_path(fence, n, e, un, ue, turn, side, wind)
            edges = [(verts, arc_sag)]
            if turn.inner_radius_m > 0.0:
                inner, inner_sag, _shared = _inner_path(fence, n, e, un, ue, turn, side, wind)
                edges.append((inner, inner_sag))
            sides.append(edges)
    else:
        k = d / v if v > 0.0 else 0.0
        sides = [[(np.array(((n, e), (n + k * vn, e + k * ve))), 0.0)]]
    hazard = _local_hazard(fence, n, e, reach + w + sag)
    if hazard is _NOTHING_NEAR:  # cannot be when tripped; kept for safety
        hazard = fence._forbidden
    best = -_INF
    best_verts, best_w = sides[0][0][0], w
    for edges in sides:
        s_side, side_verts, side_w = _INF, edges[0][0], w + edges[0][1]
        for verts, arc_sag in edges:
            s_edge = _first_hit_s(hazard, verts, w + arc_sag)
            if s_edge < s_side:
                s_side, side_verts, side_w = s_edge, verts, w + arc_sag
        if s_side > best:
            best, best_verts, best_w = s_side, side_verts, side_w
    if not _isfinite(best):
        best = d  # touched by a rounding margin only: value equals limit
    # Which kind of hazard is met first: the path point at the first contact (or its start, when already
    # within the widening) is within the widening, plus the resolution, of the one it meets.
    kind: FenceKind = "inclusion" if fence._has_inclusion else "exclusion"
    if fence._incl_hazard is not None and fence._excl_hazard is not None:
        seg = np.hypot(np.diff(best_verts[:, 0]), np.diff(best_verts[:, 1]))
        cum = np.concatenate(([0.0], np.cumsum(seg)))
        s_at = min(max(best, 0.0), float(cum[-1]))
        pn, pe = _point_at(best_verts, cum, s_at) if cum[-1] > 0.0 else (n, e)
        d_excl = float(shapely.distance(fence._excl_hazard, shapely.points((pn, pe))))
        if d_excl <= best_w + 2.0 * _CLEARANCE_RESOLUTION_M:
            kind = "exclusion"
    return kind, best


# --------------------------------------------------------------------------------- other fence queries


def contains(fence: Fence, pos_ned_m: Sequence[float]) -> bool:
    """Whether the position is inside the fence (horizontally, and below the ceiling): the arming check.

    No projection and no widening; the floor is not applied (the vehicle is on the ground when arming).
    False for non-finite input. A disabled fence contains everything.
    """
    if not fence.params.enabled:
        return True
    n, e, dn = pos_ned_m
    if not _isfinite(n + e + dn) or max(abs(n), abs(e), abs(dn)) > MAX_ABS_POS_M:
        return False
    ceiling = fence.params.altitude_ceiling_m
    if ceiling is not None and -dn >= ceiling:
        return False
    if _outside_box(fence, n, e):
        return False
    return _lower_bound(fence, n, e) > 0.0 or _inside(fence, n, e)


@dataclass(frozen=True, slots=True)
class TurnClearance:
    """One side of the fixed-wing projection: the reaction leg, then the half turn at the bank limit.

    ``side``: +1 the right turn (clockwise seen from above), -1 the left. ``margin_m``: the shortest
    horizontal distance from that path to a hazard, minus the widening and the polyline's chord error, as
    :func:`check` tests it: positive, the path stays clear by that much; zero or less, it comes within the
    widening (``-widening - chord error`` when it crosses into the hazard). ``free_path_m``: the arc length
    along the path before it first comes within the widening (inf when it never does; at most 1 cm short
    of the exact value, never over it).
    """

    side: int
    margin_m: float
    free_path_m: float


def turn_clearances(
    fence: Fence,
    pos_ned_m: Sequence[float],
    vel_ned_mps: Sequence[float],
    sigma_h_m: float,
    wind_ne_mps: tuple[float, float] = (0.0, 0.0),
    bank_rad: float = 0.0,
) -> tuple[TurnClearance, TurnClearance]:
    """Both sides of the fixed-wing fence projection, (right, left), measured exactly as :func:`check` builds
    them (the fence's reaction time and bank limit; the arc as its polyline, whose chord error is counted
    against the margin). :func:`check` trips horizontally when neither side has a positive margin.

    For the choice of the side to turn to after a trip (a re-entrant corner blocks the short way home),
    not for every tick: it always calls shapely (two distances, and the first contact on a side that has
    one). Horizontal only; the fence's vehicle kind is not consulted (the turn is what is measured).
    Non-finite input, or a fence with no horizontal hazard, gives NaN / inf margins respectively.
    ``bank_rad``: the bank at this state (right positive), rolled out first by a turn to the other side, and
    the airspeed is the whole one, as in :func:`check`.
    """
    prm = fence.params
    n, e = float(pos_ned_m[0]), float(pos_ned_m[1])
    vn, ve = float(vel_ned_mps[0]), float(vel_ned_mps[1])
    vd = float(vel_ned_mps[2]) if len(vel_ned_mps) > 2 else 0.0
    wn, we = float(wind_ne_mps[0]), float(wind_ne_mps[1])
    if (not _isfinite(n + e + vn + ve + vd + sigma_h_m + wn + we + bank_rad)
            or max(abs(n), abs(e)) > MAX_ABS_POS_M):
        bad = (TurnClearance(1, _NAN, _NAN), TurnClearance(-1, _NAN, _NAN))
        return bad
    if fence._forbidden is None:
        return TurnClearance(1, _INF, _INF), TurnClearance(-1, _INF, _INF)
    w = prm.margin_m + prm.sigma_k * max(sigma_h_m, 0.0)
    wind = _NO_WIND
    if wn != 0.0 or we != 0.0:
        vn, ve, wind = vn - wn, ve - we, (wn, we)  # as check(): the turn follows the air velocity
    v = _hypot(vn, ve)
    with np.errstate(all="ignore"):
        if v < _MIN_PATH_M:
            pt = shapely.points((n, e))
            d = float(shapely.distance(fence._forbidden, pt))
            free = _INF if d > w else 0.0
            return TurnClearance(1, d - w, free), TurnClearance(-1, d - w, free)
        un, ue = vn / v, ve / v
        turn = fixed_wing_turn(prm, _escape_speed_mps(v, vd), bank_rad)
        radius = turn.radius_m
        reach = turn.rollout_m() + _hypot(turn.leg_m, radius) + radius + _drift_m(wind, turn)
        sag_max = _WIND_SAG_FACTOR * max(ARC_CHORD_ERROR_M, radius * fence._arc_tables[-1][1]) + _leg_sag_m(turn)
        hazard = _local_hazard(fence, n, e, reach + w + sag_max)
        out = []
        for side in (1, -1):
            verts, arc_sag = _turn_path(fence, n, e, un, ue, turn, float(side), wind)
            inner: FloatArray | None = None
            corner = verts[-1]
            shared = 0
            line, geom_sag = verts, arc_sag
            if turn.inner_radius_m > 0.0:
                # the side is the area between its turn and the inner edge: the line round it, and a keep-out
                # inside it (which puts the area's distance to the hazard at 0)
                inner, inner_sag, shared = _inner_path(fence, n, e, un, ue, turn, float(side), wind)
                corner = _far_corner(verts, turn, un, ue, float(side), wind)
                line, geom_sag = _boundary(verts, corner, inner, shared), max(arc_sag, inner_sag)
            # the whole forbidden area for the distance (a tile answers exactly only within its reach)
            margin = float(shapely.distance(fence._forbidden, shapely.linestrings(line))) - w - geom_sag
            if (inner is not None and margin > -w - geom_sag
                    and _encloses(fence, n, e, reach, verts, corner, inner, shared)):
                margin = -w - geom_sag
            if margin > 0.0 or hazard is _NOTHING_NEAR:
                free = _INF
            else:
                free = _free_path_m(fence, hazard, n, e, verts, corner, inner, shared, w, arc_sag, geom_sag)
            out.append(TurnClearance(side, margin, free))
    return out[0], out[1]


def _free_path_m(fence: Fence, hazard: Any, n: float, e: float, verts: FloatArray, corner: FloatArray,
                 inner: FloatArray | None, shared: int, w: float, arc_sag: float, geom_sag: float) -> float:
    """A blocked side's free path (:func:`turn_clearances`): how far along the outer edge, or the inner one,
    before it comes within the widening of ``hazard``. When both edges keep clear, the area's far corner or a
    keep-out between the edges blocks the side, met by a turn between them, which neither edge says where: no
    sooner than the straight line to the part of the hazard within the widening of the area (the escape's side
    is not chosen for a free path that no flown turn has)."""
    free = _first_hit_s(hazard, verts, w + arc_sag)
    if inner is not None:
        free = min(free, _first_hit_s(hazard, inner, w + geom_sag))
        if free == _INF:
            near = shapely.intersection(fence._forbidden, shapely.buffer(_area(verts, corner, inner, shared),
                                                                         w + geom_sag))
            if shapely.is_empty(near):
                # the line round the area only grazes the widening (rounding): the nearest hazard, whole (an
                # empty part's distance is NaN, which would win no comparison and lose none)
                near = fence._forbidden
            free = float(shapely.distance(near, shapely.points((n, e)))) - w - geom_sag
    return max(free, 0.0)


def straight_clearance(
    fence: Fence,
    pos_ned_m: Sequence[float],
    vel_ned_mps: Sequence[float],
    sigma_h_m: float,
    wind_ne_mps: tuple[float, float] = (0.0, 0.0),
    bank_rad: float = 0.0,
) -> float:
    """How far the aircraft's course is *open*: the margin (as :func:`turn_clearances` measures it: distance
    to a hazard less the widening and the polyline's chord error) of the path flown wings level from here
    for as long as the fence projection's escape takes (:attr:`FixedWingTurn.duration_s`), in the air mass
    and drifting with the wind. A bank is rolled out first at the loops' roll rate (the arc at that bank
    for half the roll-out time, as :func:`_turn_path` counts it), and the straight part is flown at the
    turn's airspeed (the faster one the loops may fly: the farther it reaches, the more it checks).

    An escape turn is judged on what follows it: a half turn at the bank limit ends heading back the way
    the aircraft came, which in a lobe of the range with the wind towards its wall is a course from which
    neither turn clears. A course open for the whole escape's time is one the aircraft can hold while the
    behaviour after the escape takes over (``merlin.autopilot.fixedwing_behaviours``; scenarios
    ``fw_adv_lobe_dive_north_wind`` and ``fw_adv_lobe_crash_northeast_wind``). NaN for non-finite input,
    inf for a fence with no horizontal hazard."""
    prm = fence.params
    n, e = float(pos_ned_m[0]), float(pos_ned_m[1])
    vn, ve = float(vel_ned_mps[0]), float(vel_ned_mps[1])
    vd = float(vel_ned_mps[2]) if len(vel_ned_mps) > 2 else 0.0
    wn, we = float(wind_ne_mps[0]), float(wind_ne_mps[1])
    if (not _isfinite(n + e + vn + ve + vd + sigma_h_m + wn + we + bank_rad)
            or max(abs(n), abs(e)) > MAX_ABS_POS_M or max(abs(wn), abs(we)) > MAX_SPEED_MPS):
        return _NAN
    if fence._forbidden is None:
        return _INF
    w = prm.margin_m + prm.sigma_k * max(sigma_h_m, 0.0)
    vn, ve = vn - wn, ve - we  # the air velocity: the straight line is flown in the air mass
    v = _hypot(vn, ve)
    with np.errstate(all="ignore"):
        if v < _MIN_PATH_M:
            return float(shapely.distance(fence._forbidden, shapely.points((n, e)))) - w
        un, ue = vn / v, ve / v
        turn = fixed_wing_turn(prm, _escape_speed_mps(v, vd), bank_rad)
        sag = 0.0
        if turn.rollout_s > 0.0:
            side = -1.0 if turn.bank_rad > 0.0 else 1.0  # a turn to this side would roll the bank out
            head, t_head, sag = _rollout_arc(n, e, un, ue, turn, side)
            un, ue = _rolled_out_heading(un, ue, turn, side)
        else:
            head, t_head = np.array(((n, e),)), np.zeros(1)
        t_end = max(turn.duration_s, float(t_head[-1]))
        run = turn.v_turn_mps * (t_end - float(t_head[-1]))
        end = head[-1] + run * np.array((un, ue))
        verts = np.vstack((head, end[None, :]))
        t = np.concatenate((t_head, (t_end,)))
        verts[:, 0] += wn * t
        verts[:, 1] += we * t
        return float(shapely.distance(fence._forbidden, shapely.linestrings(verts))) - w - sag * _WIND_SAG_FACTOR


def wind_triangle_ne(vel_ned_mps: Sequence[float], airspeed_mps: float, yaw_rad: float) -> tuple[float, float]:
    """The horizontal wind from the wind triangle: ground velocity minus the air velocity along the heading.

    The air velocity's horizontal part is ``sqrt(airspeed^2 - v_d^2)`` along the yaw (no sideslip, no
    vertical wind: the coordinated flight a fixed wing's autopilot keeps), as a fixed-wing autopilot
    without a wind filter estimates it. (0, 0) when the airspeed is not a usable number (not finite, or
    below 1 m/s: on the catapult or a broken sensor), so the projection falls back to the still-air turn;
    a non-finite ground velocity or yaw gives NaN, which :func:`check` treats as broken input."""
    if not (_isfinite(airspeed_mps) and airspeed_mps >= 1.0):
        return _NO_WIND
    vn, ve, vd = vel_ned_mps
    va_h = math.sqrt(max(airspeed_mps * airspeed_mps - vd * vd, 0.0))
    return (vn - va_h * math.cos(yaw_rad), ve - va_h * math.sin(yaw_rad))


#: How far above the floor's trip height a climbing vehicle must be before the floor applies: more than the
#: tick-to-tick noise of an estimated height (a few decimetres), so that the tick after the floor starts to
#: apply does not trip it (``adv_floor_takeoff`` tripped on noise of 1 mm without it).
FLOOR_CLEAR_HYSTERESIS_M: Final = 1.0


def clear_of_floor(fence: Fence, pos_ned_m: Sequence[float], sigma_v_m: float) -> bool:
    """True when the vehicle is above the floor by what :func:`check` keeps clear of it (``margin_m +
    sigma_k * sigma_v`` with a projection, and a fixed wing's ``recovery_height_m``, nothing in position-only
    mode) plus
    :data:`FLOOR_CLEAR_HYSTERESIS_M`, or when there is no floor.

    The core applies the floor from the first tick this holds after leaving the ground (and until the
    vehicle is on the ground again): a floor judged from the moment the vehicle is airborne trips during
    every take-off that starts below it (scenario ``adv_floor_takeoff``). A non-finite input is never clear.
    """
    prm = fence.params
    floor = prm.altitude_floor_m
    if floor is None or not prm.enabled:
        return True
    h = -pos_ned_m[2] - FLOOR_CLEAR_HYSTERESIS_M
    if prm.mode == "position_only":
        return h > floor
    return h - (prm.margin_m + prm.sigma_k * sigma_v_m) - prm.recovery_height_m > floor


def nearest_boundary_ne(fence: Fence, n: float, e: float) -> tuple[float, float, float] | None:
    """The nearest horizontal hazard: ``(distance_m, un, ue)``, with ``(un, ue)`` the unit direction from the
    position towards it (outward); a negative distance when the position is already outside, the direction
    then pointing further out (away from the allowed area). None without horizontal zones, for non-finite
    input, or exactly on a boundary. For the operator's fence (:func:`merlin.core.shaping.operator_command`,
    as ArduPilot's AC_Avoid): one shapely call, made only while a fenced pilot flies."""
    if fence._forbidden is None or not _isfinite(n + e) or max(abs(n), abs(e)) > MAX_ABS_POS_M:
        return None
    pt = shapely.points((n, e))
    inside = _inside(fence, n, e)
    other = fence._forbidden if inside else (fence._allowed if fence._has_inclusion else fence._excl_boundary)
    q = shapely.get_coordinates(shapely.shortest_line(pt, other))[1]
    dn, de = float(q[0]) - n, float(q[1]) - e
    d = _hypot(dn, de)
    if not d > 0.0:
        return None
    if inside:
        return d, dn / d, de / d
    return -d, -dn / d, -de / d


def boundary_constraints_ne(fence: Fence, n: float, e: float, radius_m: float) -> list[tuple[float, float, float]]:
    """Every horizontal hazard edge within ``radius_m``: ``(distance_m, un, ue)`` per edge, the unit direction
    from the position towards the edge's nearest point (outward), as ArduPilot's AC_Avoid limits a pilot
    against each fence segment, not only the nearest one: near a corner or a keep-out the nearest edge alone
    leaves the stick free to fly out through the next one (scenario ``adv_pilot_regrab_ceiling``'s
    companion property test). Outside the allowed area (or inside a keep-out) the one constraint is
    :func:`nearest_boundary_ne`'s (negative distance, pointing further out). Empty without horizontal zones,
    for non-finite input, or with nothing within ``radius_m``.

    The distance to an edge falls no faster than the velocity's component towards its nearest point, so a
    speed limit on each of these components bounds the approach to every edge at once."""
    if fence._forbidden is None or not _isfinite(n + e + radius_m) or max(abs(n), abs(e)) > MAX_ABS_POS_M:
        return []
    if not _inside(fence, n, e):
        near = nearest_boundary_ne(fence, n, e)
        return [] if near is None else [near]
    hazard = _local_hazard(fence, n, e, radius_m)
    if hazard is _NOTHING_NEAR:
        return []
    out: list[tuple[float, float, float]] = []
    for ring in shapely.get_rings(shapely.get_parts(hazard)):
        xy = shapely.get_coordinates(ring)
        a, b = xy[:-1], xy[1:]
        ab = b - a
        ll = np.einsum("ij,ij->i", ab, ab)
        t = np.clip(np.einsum("ij,ij->i", np.array((n, e)) - a, ab) / np.where(ll > 0.0, ll, 1.0), 0.0, 1.0)
        q = a + ab * t[:, None]
        dq = q - np.array((n, e))
        d = np.hypot(dq[:, 0], dq[:, 1])
        for i in np.nonzero((d < radius_m) & (d > 0.0))[0]:
            di = float(d[i])
            out.append((di, float(dq[i, 0]) / di, float(dq[i, 1]) / di))
    return out


def signed_margin_m(fence: Fence, pos_ned_m: Sequence[float], *, airborne: bool = False) -> float:
    """Distance to the nearest fence boundary: positive inside, negative outside (metrics and plots).

    Horizontal boundaries and the ceiling; the floor too when ``airborne``. +inf for a fence with no
    limits at all, NaN for non-finite input or beyond ``MAX_ABS_POS_M``. Not for the per-tick path (it always calls shapely).
    """
    n, e, dn = pos_ned_m
    if not _isfinite(n + e + dn) or max(abs(n), abs(e), abs(dn)) > MAX_ABS_POS_M:
        return _NAN
    h = -dn
    out = _signed_h(fence, n, e)
    prm = fence.params
    if prm.altitude_ceiling_m is not None:
        out = min(out, prm.altitude_ceiling_m - h)
    if airborne and prm.altitude_floor_m is not None:
        out = min(out, h - prm.altitude_floor_m)
    return out


def signed_margins_m(fence: Fence, pos_ned_m: FloatArray, airborne: FloatArray) -> FloatArray:
    """:func:`signed_margin_m` for many points at once (one shapely call per geometry instead of one per
    point): ``pos_ned_m`` is (N, 3), ``airborne`` (N,) booleans; element i equals
    ``signed_margin_m(fence, pos_ned_m[i], airborne=airborne[i])`` exactly (the same GEOS distances; a test
    holds the two together). For the simulator's log, whose margins are measured after the run."""
    pos = np.asarray(pos_ned_m, dtype=float).reshape(-1, 3)
    air = np.asarray(airborne, dtype=bool).reshape(-1)
    n, e, dn = pos[:, 0], pos[:, 1], pos[:, 2]
    with np.errstate(invalid="ignore", over="ignore"):
        valid = np.isfinite(n + e + dn) & (np.max(np.abs(pos), axis=1) <= MAX_ABS_POS_M)
    out = np.full(n.shape, _INF)
    if fence._forbidden is not None and np.any(valid):
        vn, ve = n[valid], e[valid]
        if fence._has_inclusion:
            inside = shapely.contains_xy(fence._allowed, vn, ve)
            outer = fence._allowed
        else:
            inside = ~shapely.intersects_xy(fence._forbidden, vn, ve)
            outer = fence._excl_boundary
        pts = shapely.points(np.stack((vn, ve), axis=1))
        h = np.empty(vn.shape)
        h[inside] = shapely.distance(fence._forbidden, pts[inside])
        h[~inside] = -shapely.distance(outer, pts[~inside])
        out[valid] = h
    prm = fence.params
    up = -dn
    if prm.altitude_ceiling_m is not None:
        out = np.where(valid, np.minimum(out, prm.altitude_ceiling_m - up), out)
    if prm.altitude_floor_m is not None:
        out = np.where(valid & air, np.minimum(out, up - prm.altitude_floor_m), out)
    out[~valid] = _NAN
    return out


def trigger_distance_m(
    params: FenceParams,
    speed_mps: float,
    heading_rad: float = 0.0,
    sigma_h_m: float = 0.0,
    accel_mps2: float = 0.0,
) -> float:
    """Distance from a straight boundary at which :func:`check` trips an approach at this speed.

    ``heading_rad`` is the angle between the horizontal velocity and the boundary's outward normal (0:
    head-on; pi/2: parallel). Multirotor: ``max(0, d cos(heading)) + widening``. Fixed wing: the better
    (away) turn reaches ``leg cos(heading) + R (1 - |sin(heading)|)`` towards the boundary. Position-only
    mode: 0 (it trips on the boundary). For the reviewer's "trigger distance against speed and heading"
    curve; :func:`check` agrees with it to the arc chord error (fixed wing) on a long straight wall.
    ``accel_mps2`` (multirotor): the acceleration the command demands along the velocity during the
    reaction time (capped at ``max_h_accel_mps2``), as :func:`check`'s ``demand_vel_ned_mps``.
    """
    if params.mode == "position_only":
        return 0.0
    v = abs(speed_mps)
    w = params.margin_m + params.sigma_k * sigma_h_m
    c = math.cos(heading_rad)
    if params.vehicle == "fixed_wing":
        if c <= 0.0:
            return w
        turn = fixed_wing_turn(params, v)
        return turn.leg_m * c + turn.radius_m * (1.0 - abs(math.sin(heading_rad))) + w
    tr = params.reaction_time_s
    a = min(max(accel_mps2, 0.0), params.max_h_accel_mps2)
    if a > 0.0:
        vr = v + a * tr
        d = 0.5 * (v + vr) * tr + vr * vr / (2.0 * params.max_h_decel_mps2)
        return max(0.0, d * c) + w + a * tr * tr / 8.0
    d = v * tr + v * v / (2.0 * params.max_h_decel_mps2)
    return max(0.0, d * c) + w
