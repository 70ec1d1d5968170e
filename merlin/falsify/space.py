"""The adversary's freedom, as boxes the optimiser searches: one box per adversary class.

A point of a class's box is a vector in [0, 1]^d; :meth:`AdversaryClass.scenario` turns it into an
ordinary scenario (the configuration inlined, so ``merlin sim`` reproduces it alone). Each coordinate is a
named parameter with a physical range (linear, logarithmic for magnitudes spanning decades, or circular
for headings). Geometry comes from the range itself (:class:`Site`): the vehicle starts ``distance_m``
inside the boundary of the allowed area (inclusion zones less keep-outs) at the point ``edge_pos`` of the
way along it, so every edge, corner and keep-out is reachable, at any distance, and every heading is taken
relative to that edge's outward normal.

A fixed wing cannot hover: it starts flying its course at cruise airspeed in the run's wind. A start from
which Merlin's own fence projection already trips is a state no authority could have handed it (the
trusted side would have turned away long before, and a controller flying it there would have been revoked
earlier), so a breach from it is not the adversary's doing: such a start slides back along its course, in
steps of :data:`START_STEP_M`, until the projection (the core's :func:`merlin.core.geofence.check`, with the
start's wind and a good GPS's sigma) is clear (tests/falsify/test_falsify.py,
``test_a_fixed_wing_start_the_projection_trips_slides_back_along_its_course``).

The classes (multirotor): ``velocity`` (setpoint steps and ramps of any size the validator accepts, any
heading and climb), ``velocity_crash`` and ``velocity_hang`` (the same with the process crashing or
hanging at a chosen moment of the approach), ``tilt`` (attitude setpoints), ``operator`` (the pilot's
sticks around a takeover: a grab, a release and a re-grab at chosen moments and directions). Fixed wing:
``fw_velocity``, ``fw_velocity_crash``, ``fw_pull_push`` (pull-up at low power, push at high power, banked).
Every class has the steady wind's speed and direction among its parameters.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely
from shapely.geometry import LineString, Point

from merlin.config.loader import ConfigError
from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.geofence import check
from merlin.core.step import MAX_SETPOINT_VELOCITY_MPS
from sims.scenario import Scenario, default_period, period_problems

VEHICLES = {"multirotor": "quadrotor_default", "aerosonde": "aerosonde"}
#: the runs' tick: the multirotor's, the scenarios' default; the fixed wing's, its scenarios' 200 Hz
MR_DT_S: float = Scenario.model_fields["dt_s"].default
FW_DT_S = 0.005
ADVERSARIES = "experimental_controllers.adversaries_search"
#: The steady wind the search may blow (m/s): a multirotor's range is flown up to a fresh breeze, a fixed
#: wing's up to about half its cruise airspeed.
MAX_WIND_MPS = {"multirotor": 8.0, "aerosonde": 12.0}
#: The longest approach a run flies before the stop is judged: a slower adversary has no worse stop.
MAX_APPROACH_S = {"multirotor": 20.0, "aerosonde": 30.0}
#: After the adversary's event (boundary, ceiling, crash), the run goes on this long: the stop and the
#: start of the trusted behaviour that follows.
SETTLE_S = {"multirotor": 8.0, "aerosonde": 20.0}
#: A ramp at or above this rate is sent as a step (the setpoint jumps to the target in one call).
STEP_ACCEL_MPS2 = 300.0
#: The longest stretch of a multirotor's trusted return a run flies, when the straight line home from the
#: approach's end leaves the range (a return that cuts a corner or crosses a keep-out does so early).
MAX_RETURN_S = 40.0
#: The step by which a fixed wing's start slides back along its course until its projection is clear.
START_STEP_M = 10.0
#: The position sigma the start's projection is judged with (a good GPS, as ``min_clear_m`` assumes).
START_SIGMA_M = 1.0
#: The airspeed a fixed wing starts at (the fixed-wing scenarios' cruise).
FW_START_AIRSPEED_MPS = 22.0


@dataclass(frozen=True, slots=True)
class Param:
    """One coordinate: its name and physical range; ``scale`` is ``lin``, ``log`` or ``circ`` (degrees,
    wrapping)."""

    name: str
    lo: float
    hi: float
    scale: str = "lin"

    def value(self, u: float) -> float:
        if self.scale == "circ":  # unbounded for the optimiser: a heading wraps
            return float(self.lo + (self.hi - self.lo) * (float(u) % 1.0))
        u = min(max(float(u), 0.0), 1.0)
        if self.scale == "log":
            return float(self.lo * (self.hi / self.lo) ** u)
        return float(self.lo + (self.hi - self.lo) * u)


@dataclass(frozen=True)
class Site:
    """The range as the search needs it: the allowed area, its rings (outer boundaries and keep-out
    holes) with their lengths, the altitude limits and the configuration that flies it."""

    cfg: MerlinConfig
    cfg_json: dict[str, Any]
    vehicle: str
    allowed: Any
    rings: tuple[Any, ...]
    ring_cum_m: tuple[float, ...]
    ceiling_m: float | None
    floor_m: float | None
    min_clear_m: float
    fence: Any = None  # the core's fence (merlin.core.geofence.Fence), for the start's projection
    core_dt_s: float | None = None  # the trusted core's period in every run (the scenarios' core_dt_s)
    nav_dt_s: float | None = None  # the IMU voter's and the fusion EKF's period in every run (nav_dt_s)

    @property
    def perimeter_m(self) -> float:
        return self.ring_cum_m[-1]

    def edge_point(self, u: float) -> tuple[np.ndarray, np.ndarray]:
        """The point ``u`` of the way along all rings and its inward unit normal (north, east)."""
        s = min(max(u, 0.0), 1.0 - 1e-9) * self.perimeter_m
        i = int(np.searchsorted(np.asarray(self.ring_cum_m), s, side="right"))
        ring = self.rings[i]
        local = s - (self.ring_cum_m[i - 1] if i else 0.0)
        p = np.array(ring.interpolate(local).coords[0])
        a = np.array(ring.interpolate(max(local - 0.5, 0.0)).coords[0])
        b = np.array(ring.interpolate(min(local + 0.5, ring.length)).coords[0])
        t = b - a
        n = np.array([-t[1], t[0]]) / (np.hypot(*t) or 1.0)
        if not self.allowed.contains(Point(*(p + 0.5 * n))):
            n = -n
        return p, n

    def start(self, u: float, distance_m: float) -> tuple[np.ndarray, np.ndarray]:
        """The start ``distance_m`` inward from edge point ``u`` and that edge's outward normal. Where the
        range is narrower (a non-convex corner, a keep-out nearby) the start comes closer to the edge, and
        never nearer to any boundary than ``min_clear_m`` (a start the fence would already trip is no
        adversary's doing)."""
        p, n = self.edge_point(u)
        clear = self.allowed.buffer(-self.min_clear_m)
        d = max(distance_m, self.min_clear_m)
        while d > self.min_clear_m:
            q = p + d * n
            if clear.contains(Point(*q)):
                return q, -n
            d *= 0.8
        from shapely.ops import nearest_points

        q = np.array(nearest_points(clear, Point(*p))[0].coords[0])
        return q, -n

    def distance_along(self, start: np.ndarray, heading_rad: float, max_m: float = 5000.0) -> float:
        """How far a straight course from ``start`` runs before it meets a boundary of the allowed area."""
        end = start + max_m * np.array([math.cos(heading_rad), math.sin(heading_rad)])
        hit = LineString([tuple(start), tuple(end)]).intersection(self.allowed.boundary)
        if hit.is_empty:
            return max_m
        return float(shapely.distance(Point(*start), hit))

    def return_leaves_range(self, at: np.ndarray) -> float:
        """The length of the straight line from ``at`` home, when it leaves the allowed area (0 if not): a
        trusted return that flew it would cross a keep-out or the outside of a non-convex range."""
        seg = LineString([tuple(at), (0.0, 0.0)])
        return 0.0 if self.allowed.buffer(1e-6).covers(seg) else float(seg.length)


def load_site(cfg: MerlinConfig, vehicle: str, source: str, core_dt_s: float | None = None,
              nav_dt_s: float | None = None) -> Site:
    """The range of ``cfg`` as the search flies it with ``vehicle``; ``core_dt_s``: every run's trusted core
    at that period, ``nav_dt_s``: every run's IMU voter and fusion EKF (each a whole number of the vehicle's
    tick, at most 20 ms; None: the scenarios' default, 10 ms rounded down to whole ticks, written into every
    run so that a worst case's file flies what the search flew)."""
    if vehicle not in VEHICLES:
        raise ConfigError(source, [f"--vehicle: {vehicle!r}; allowed: {sorted(VEHICLES)}"])
    tick = FW_DT_S if vehicle == "aerosonde" else MR_DT_S
    problems = period_problems(tick, f"the {vehicle}", core_dt_s, nav_dt_s)
    if problems:
        raise ConfigError(source, problems)
    core_dt_s = default_period(tick) if core_dt_s is None else core_dt_s
    nav_dt_s = default_period(tick) if nav_dt_s is None else nav_dt_s
    want = "fixed_wing" if vehicle == "aerosonde" else "multirotor"
    if cfg.vehicle.type != want:
        raise ConfigError(source, [f"vehicle.type: {cfg.vehicle.type!r}, but --vehicle {vehicle} flies a {want}"
                                   f" (give a {want} configuration or --vehicle "
                                   f"{'aerosonde' if want == 'multirotor' else 'multirotor'})"])
    if not cfg.geofence.enabled:
        raise ConfigError(source, ["geofence.enabled: false; the falsifier searches for fence breaches and "
                                   "needs the fence on"])
    core = build_core_config(cfg, source=source)
    fence = core.fence
    if fence is None or fence.allowed_area is None:
        raise ConfigError(source, ["geofence: no inclusion zone; the falsifier needs a bounded range "
                                   "(inclusion_polygons or inclusion_circles)"])
    allowed = fence.allowed_area
    rings: list[Any] = []
    for poly in getattr(allowed, "geoms", [allowed]):
        rings.append(poly.exterior)
        rings.extend(poly.interiors)
    cum = tuple(float(x) for x in np.cumsum([r.length for r in rings]))
    gf = cfg.geofence
    # a start nearer than this would be inside the fence's own margin plus k sigma of a good GPS (the
    # grant is refused there), with a few metres for the take-over's hover
    min_clear = gf.margin_m + gf.sigma_k * 1.0 + 3.0
    if vehicle == "aerosonde":
        min_clear = max(min_clear, 2.5 * 22.0 ** 2 / (9.80665 * math.tan(math.radians(cfg.vehicle.bank_limit_deg))))
    return Site(cfg, cfg.model_dump(mode="json"), vehicle, allowed, tuple(rings), cum,
                gf.altitude_ceiling_m, gf.altitude_floor_m, min_clear, fence, core_dt_s, nav_dt_s)


Builder = Callable[["AdversaryClass", Site, dict[str, float], int], dict[str, Any]]


@dataclass(frozen=True)
class AdversaryClass:
    name: str
    vehicle: str
    params: tuple[Param, ...]
    build: Builder
    description: str

    @property
    def dim(self) -> int:
        return len(self.params)

    def values(self, u: np.ndarray) -> dict[str, float]:
        return {p.name: p.value(x) for p, x in zip(self.params, u, strict=True)}

    def scenario(self, site: Site, u: np.ndarray, seed: int) -> dict[str, Any]:
        return self.build(self, site, self.values(u), seed)


# ------------------------------------------------------------------------------------------- builders

def _heights(site: Site) -> tuple[float, float]:
    """The start heights searched: clear of the ceiling and the floor by the fence's margin plus k sigma and
    3 m (a start whose projection already trips the fence is not the adversary's doing: it would begin
    with a revocation of nobody, and the grant would be refused)."""
    gf = site.cfg.geofence
    clear = gf.margin_m + gf.sigma_k * 1.0 + 3.0
    ceiling = site.ceiling_m if site.ceiling_m is not None else 150.0
    if site.vehicle == "aerosonde":
        floor = site.floor_m if site.floor_m is not None else 20.0
        # a fixed wing's floor projection counts the stall recovery's bounded height loss: below it the
        # fence trips at the start and no grant is given (merlin.core.geofence._floor_drop_m)
        rec = site.fence.params.recovery_height_m if site.fence is not None and site.floor_m is not None else 0.0
        return floor + clear + rec, ceiling - max(clear, 10.0)
    if site.floor_m is not None:
        return site.floor_m + clear, ceiling - clear
    return 4.0, ceiling - clear


def _common(site: Site, v: dict[str, float], seed: int, name: str) -> tuple[dict[str, Any], np.ndarray, np.ndarray]:
    start, outward = site.start(v["edge_pos"], v["distance_m"])
    lo, hi = _heights(site)
    h0 = lo + (hi - lo) * v["height_frac"]
    base_yaw = math.degrees(math.atan2(outward[1], outward[0]))
    w = math.radians(v["wind_dir_deg"])
    sc: dict[str, Any] = {
        "name": f"falsify_{name}",
        "description": f"merlin falsify: adversary class {name}",
        "duration_s": 30.0,
        "seed": seed,
        "vehicle": VEHICLES[site.vehicle],
        "config": site.cfg_json,
        "initial": {"pos_ned_m": [round(float(start[0]), 3), round(float(start[1]), 3), round(-h0, 3)],
                    "yaw_deg": round(base_yaw, 3)},
        "wind": {"steady_ned_mps": [round(v["wind_mps"] * math.cos(w), 4), round(v["wind_mps"] * math.sin(w), 4),
                                    0.0]},
        "gcs": [{"t": 0.0, "command": "arm"}, {"t": 0.0, "command": "hold"}],
        "expectations": [{"type": "no_fence_breach", "name": "the vehicle stays inside the range"}],
    }
    if site.vehicle == "aerosonde":
        sc["dt_s"] = FW_DT_S  # the JSBSim model and the core at 200 Hz, as the fixed-wing scenarios
        sc["initial"]["airspeed_mps"] = 22.0
    if site.core_dt_s is not None:
        sc["core_dt_s"] = site.core_dt_s
    if site.nav_dt_s is not None:
        sc["nav_dt_s"] = site.nav_dt_s
    return sc, start, outward


def start_projection_clear(site: Site, pos_ne: np.ndarray, h_m: float, heading_deg: float,
                           wind_ne_mps: tuple[float, float]) -> bool:
    """Whether Merlin's own fence projection is clear for a fixed wing at ``pos_ne`` and ``h_m`` flying
    ``heading_deg`` at the start airspeed in the wind ``wind_ne_mps`` (wings level)."""
    h = math.radians(heading_deg)
    vn = FW_START_AIRSPEED_MPS * math.cos(h) + wind_ne_mps[0]
    ve = FW_START_AIRSPEED_MPS * math.sin(h) + wind_ne_mps[1]
    res = check(site.fence, (float(pos_ne[0]), float(pos_ne[1]), -h_m), (vn, ve, 0.0), START_SIGMA_M,
                START_SIGMA_M, True, (float(wind_ne_mps[0]), float(wind_ne_mps[1])))
    return not res.tripped


def _viable_fw_start(site: Site, sc: dict[str, Any], start: np.ndarray, heading_deg: float) -> np.ndarray:
    """The fixed wing's start slid back along its course until its projection is clear (the module's
    docstring says why); a start that is clear stays where it is. When no point of the course behind it
    is clear (a range too small for the aircraft's turn), the run starts at home on the same course."""
    h0 = -float(sc["initial"]["pos_ned_m"][2])
    wn, we, _ = sc["wind"]["steady_ned_mps"]
    back = -np.array([math.cos(math.radians(heading_deg)), math.sin(math.radians(heading_deg))])
    p = np.asarray(start, dtype=float)
    clear_area = site.allowed.buffer(-site.min_clear_m)
    for _ in range(400):
        if start_projection_clear(site, p, h0, heading_deg, (wn, we)):
            break
        q = p + START_STEP_M * back
        if not clear_area.contains(Point(*q)):
            p = np.zeros(2)
            break
        p = q
    sc["initial"]["pos_ned_m"][0] = round(float(p[0]), 3)
    sc["initial"]["pos_ned_m"][1] = round(float(p[1]), 3)
    return p


def _abs_heading(outward: np.ndarray, rel_deg: float) -> float:
    return math.degrees(math.atan2(outward[1], outward[0])) + rel_deg


def _duration(site: Site, start: np.ndarray, heading_deg: float, speed: float, climb: float, h0: float,
              lead_s: float, frac_end: float | None = None) -> tuple[float, float]:
    """The run's length (the approach, capped, then the settle time, plus a return home when the straight
    return would leave the range) and the estimated time to the event (boundary or ceiling)."""
    v = site.vehicle
    v_eff = max(min(speed, 35.0 if v == "aerosonde" else 25.0), 1.0)
    dist = site.distance_along(start, math.radians(heading_deg))
    t_event = dist / v_eff
    if climb > 0.1 and site.ceiling_m is not None:
        t_event = min(t_event, max(site.ceiling_m - h0, 0.0) / min(climb, 15.0))
    if climb < -0.1:
        t_event = min(t_event, max(h0 - (site.floor_m or 0.0), 0.0) / min(-climb, 15.0))
    t_event = min(t_event, MAX_APPROACH_S[v])
    if frac_end is not None:
        t_event = min(t_event, frac_end * t_event + 1.0)
    total = lead_s + t_event + SETTLE_S[v]
    h = math.radians(heading_deg)
    reach = start + min(dist, v_eff * t_event) * np.array([math.cos(h), math.sin(h)])
    ret = site.return_leaves_range(reach)
    if ret > 0.0 and v == "multirotor":
        cruise = site.cfg.trusted.cruise_speed_mps
        # the return past the keep-out or the corner, and the climb before it
        total += min(ret / cruise + 10.0, MAX_RETURN_S)
    return round(total, 1), t_event


def _velocity(cls: AdversaryClass, site: Site, v: dict[str, float], seed: int) -> dict[str, Any]:
    sc, start, outward = _common(site, v, seed, cls.name)
    heading = _abs_heading(outward, v["heading_rel_deg"])
    accel = 0.0 if v["accel_mps2"] >= STEP_ACCEL_MPS2 else v["accel_mps2"]
    h0 = -sc["initial"]["pos_ned_m"][2]
    if site.vehicle == "aerosonde":
        start = _viable_fw_start(site, sc, start, heading)
    lead = 1.6 + v["start_after_s"]
    params: dict[str, Any] = {
        "start_after_s": round(v["start_after_s"], 3), "heading_deg": round(heading, 3),
        "speed_mps": round(v["speed_mps"], 3), "climb_mps": round(v["climb_mps"], 3), "accel_mps2": round(accel, 3),
    }
    frac = v.get("end_frac")
    dur, t_event = _duration(site, start, heading, v["speed_mps"], v["climb_mps"], h0, lead, frac)
    if frac is not None:
        params["end_after_s"] = round(max(frac * t_event, 0.0), 3)
        params["end_mode"] = "hang" if cls.name.endswith("hang") else "crash"
    if site.vehicle == "aerosonde":
        params["request_at_s"] = 1.0
        params["yaw_to_course"] = True
        sc["initial"]["yaw_deg"] = round(heading, 3)
    sc["controller"] = {"type": f"{ADVERSARIES}:SearchVelocity", "params": params}
    sc["duration_s"] = dur
    return sc


def _tilt(cls: AdversaryClass, site: Site, v: dict[str, float], seed: int) -> dict[str, Any]:
    sc, start, outward = _common(site, v, seed, cls.name)
    heading = _abs_heading(outward, v["heading_rel_deg"])
    h0 = -sc["initial"]["pos_ned_m"][2]
    # the speed a sustained tilt reaches is not known before the flight; the envelope's horizontal velocity
    # limit (or the vehicle's maximum) stands for it in the run's length
    speed = max(1.0, 9.80665 * math.tan(math.radians(v["tilt_deg"])) * 3.0)
    dur, _ = _duration(site, start, heading, speed, 0.0, h0, 1.6)
    sc["controller"] = {"type": f"{ADVERSARIES}:SearchTilt", "params": {
        "heading_deg": round(heading, 3), "tilt_deg": round(v["tilt_deg"], 3),
        "tilt_rate_degps": round(v["tilt_rate_degps"], 3), "thrust_bias": round(v["thrust_bias"], 4),
        "hover_thrust": site.cfg.vehicle.hover_thrust}}
    sc["duration_s"] = dur
    return sc


def _stick(rel_heading_rad: float, mag: float) -> tuple[float, float]:
    """Pitch and roll stick for a horizontal direction relative to the vehicle's nose (stick forward flies
    forward, stick right flies right)."""
    return round(mag * math.cos(rel_heading_rad), 4), round(mag * math.sin(rel_heading_rad), 4)


def _operator(cls: AdversaryClass, site: Site, v: dict[str, float], seed: int) -> dict[str, Any]:
    sc, start, outward = _common(site, v, seed, cls.name)
    yaw = math.radians(sc["initial"]["yaw_deg"])  # the nose points outward: stick directions relative to it
    heading1 = _abs_heading(outward, v["stick1_rel_deg"])
    h0 = -sc["initial"]["pos_ned_m"][2]
    op_speed = site.cfg.operator.max_speed_h_mps * max(v["stick1_mag"], 0.1)
    t_grab = v["grab_at_s"]
    _, t_event = _duration(site, start, heading1, op_speed, 0.0, h0, t_grab)
    t_release = t_grab + max(v["release_frac"] * t_event, 0.3)
    t_regrab = t_release + v["regrab_gap_s"]
    p1, r1 = _stick(math.radians(heading1) - yaw, v["stick1_mag"])
    p2, r2 = _stick(math.radians(_abs_heading(outward, v["stick2_rel_deg"])) - yaw, v["stick2_mag"])
    sc["rc_connected"] = True
    sc["operator"] = [
        {"t": round(t_grab, 3), "takeover": True, "pitch": p1, "roll": r1, "throttle": round(v["throttle1"], 4)},
        {"t": round(t_release, 3), "takeover": False},
        {"t": round(t_regrab, 3), "takeover": True, "pitch": p2, "roll": r2, "throttle": round(v["throttle2"], 4)},
    ]
    dist2 = site.distance_along(start, math.radians(_abs_heading(outward, v["stick2_rel_deg"])))
    after = min(dist2 / max(site.cfg.operator.max_speed_h_mps, 1.0), MAX_APPROACH_S["multirotor"])
    sc["duration_s"] = round(t_regrab + min(site.cfg.operator.override_grace_s, after) + SETTLE_S["multirotor"], 1)
    return sc


def _pull_push(cls: AdversaryClass, site: Site, v: dict[str, float], seed: int) -> dict[str, Any]:
    sc, start, outward = _common(site, v, seed, cls.name)
    sc["initial"]["yaw_deg"] = round(_abs_heading(outward, v["heading_rel_deg"]), 3)
    _viable_fw_start(site, sc, start, sc["initial"]["yaw_deg"])
    sc["controller"] = {"type": f"{ADVERSARIES}:SearchPullPush", "params": {
        "request_at_s": 1.0, "start_after_s": 1.0,
        "pull_pitch_deg": round(v["pull_pitch_deg"], 3), "pull_rate_degps": round(v["pull_rate_degps"], 3),
        "pull_throttle": round(v["pull_throttle"], 4), "push_after_s": round(v["push_after_s"], 3),
        "push_pitch_deg": round(v["push_pitch_deg"], 3), "push_rate_degps": round(v["push_rate_degps"], 3),
        "push_throttle": round(v["push_throttle"], 4), "roll_deg": round(v["roll_deg"], 3)}}
    sc["duration_s"] = round(3.0 + v["push_after_s"] + SETTLE_S["aerosonde"], 1)
    return sc


# --------------------------------------------------------------------------------------------- classes

def _place(vehicle: str) -> tuple[Param, ...]:
    far = (10.0, 150.0) if vehicle == "multirotor" else (150.0, 1200.0)
    return (Param("edge_pos", 0.0, 1.0), Param("distance_m", far[0], far[1], "log"), Param("height_frac", 0.0, 1.0))


def _wind(vehicle: str) -> tuple[Param, ...]:
    return (Param("wind_mps", 0.0, MAX_WIND_MPS[vehicle]), Param("wind_dir_deg", 0.0, 360.0, "circ"))


def _velocity_params(vehicle: str) -> tuple[Param, ...]:
    lo = 1.0 if vehicle == "multirotor" else 10.0
    return (*_place(vehicle), Param("heading_rel_deg", -180.0, 180.0, "circ"),
            Param("speed_mps", lo, MAX_SETPOINT_VELOCITY_MPS, "log"), Param("climb_mps", -30.0, 30.0),
            Param("accel_mps2", 0.5, STEP_ACCEL_MPS2 * 1.5, "log"), Param("start_after_s", 0.0, 3.0), *_wind(vehicle))


def adversary_classes(vehicle: str) -> tuple[AdversaryClass, ...]:
    """The classes searched for ``vehicle`` (``multirotor`` or ``aerosonde``), in a fixed order."""
    end = (Param("end_frac", 0.0, 1.2),)
    if vehicle == "multirotor":
        return (
            AdversaryClass("velocity", vehicle, _velocity_params(vehicle), _velocity,
                           "velocity setpoint step or ramp, any speed up to the validator's bound, heading, climb"),
            AdversaryClass("velocity_crash", vehicle, _velocity_params(vehicle) + end, _velocity,
                           "the velocity adversary's process crashes during the approach"),
            AdversaryClass("velocity_hang", vehicle, _velocity_params(vehicle) + end, _velocity,
                           "the velocity adversary's control thread hangs (heartbeat alive) during the approach"),
            AdversaryClass("tilt", vehicle, (
                *_place(vehicle), Param("heading_rel_deg", -180.0, 180.0, "circ"), Param("tilt_deg", 0.0, 70.0),
                Param("tilt_rate_degps", 10.0, 1000.0, "log"), Param("thrust_bias", -0.3, 0.5), *_wind(vehicle)),
                _tilt, "attitude setpoint: a tilt towards any heading at any rate, any collective"),
            AdversaryClass("operator", vehicle, (
                *_place(vehicle), Param("stick1_rel_deg", -180.0, 180.0, "circ"), Param("stick1_mag", 0.0, 1.0),
                Param("throttle1", -1.0, 1.0), Param("grab_at_s", 0.5, 3.0), Param("release_frac", 0.2, 2.0),
                Param("regrab_gap_s", 0.05, 3.0, "log"), Param("stick2_rel_deg", -180.0, 180.0, "circ"),
                Param("stick2_mag", 0.0, 1.0), Param("throttle2", -1.0, 1.0), *_wind(vehicle)),
                _operator, "the pilot: takeover with a stick, release, re-grab with another stick"),
        )
    if vehicle == "aerosonde":
        return (
            AdversaryClass("fw_velocity", vehicle, _velocity_params(vehicle), _velocity,
                           "fixed wing velocity setpoint: any course, speed, climb, step or ramp"),
            AdversaryClass("fw_velocity_crash", vehicle, _velocity_params(vehicle) + end, _velocity,
                           "the fixed-wing velocity adversary's process crashes during the approach"),
            AdversaryClass("fw_pull_push", vehicle, (
                *_place(vehicle), Param("heading_rel_deg", -180.0, 180.0, "circ"),
                Param("pull_pitch_deg", 5.0, 45.0), Param("pull_rate_degps", 1.0, 30.0, "log"),
                Param("pull_throttle", 0.0, 1.0), Param("push_after_s", 0.5, 15.0),
                Param("push_pitch_deg", -45.0, 0.0), Param("push_rate_degps", 5.0, 100.0, "log"),
                Param("push_throttle", 0.0, 1.0), Param("roll_deg", -60.0, 60.0), *_wind(vehicle)),
                _pull_push, "pull-up at low power, then push at high power, banked"),
        )
    raise ConfigError("merlin falsify", [f"--vehicle: {vehicle!r}; allowed: {sorted(VEHICLES)}"])
