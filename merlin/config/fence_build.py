"""From the validated configuration to the core's :class:`~merlin.core.geofence.Fence`.

This is the edge where degrees become radians and WGS84 becomes the local NED frame about home
(:class:`merlin.geodesy.LocalFrame`). Geometry a reviewer can get wrong (a self-intersecting or
zero-area polygon, a hole outside its polygon, exclusions covering every inclusion) is reported as a
:class:`~merlin.config.loader.ConfigError` naming the file, the key path and where the defect is.

Polygon edges are straight lines in the local frame (an azimuthal equidistant projection about home; for
the few-kilometre fences of a test range a straight edge there and the geodesic between the same vertices
differ by far less than a millimetre). Circles are polygonised by the core fence, conservatively (inscribed
for inclusions, circumscribed for exclusions) with a chord error below 0.1 m (``CIRCLE_CHORD_ERROR_M``).
"""

from __future__ import annotations

import math

from merlin.config.loader import ConfigError
from merlin.config.models import FenceCircle, FencePolygon, GeofenceConfig, HomeConfig, VehicleLimits
from merlin.core.geofence import (
    MAX_ABS_POS_M,
    STANDARD_GRAVITY_MPS2,
    CircleNE,
    Fence,
    FenceModeName,
    FenceParams,
    PointNE,
    PolygonNE,
    VehicleKind,
    polygon_problem,
)
from merlin.geodesy import LocalFrame


def build_fence_params(geofence_cfg: GeofenceConfig, vehicle_cfg: VehicleLimits,
                       recovery_height_m: float = 0.0) -> FenceParams:
    """The core's fence parameters (SI units, radians) from the configuration. ``recovery_height_m``: a fixed
    wing's stall-recovery height bound, which needs the envelope (:func:`merlin.config.runtime.build_core_config`
    passes :func:`merlin.autopilot.fixedwing_recovery.recovery_height_bound_m`)."""
    mode: FenceModeName = (
        "position_only" if geofence_cfg.mode.value == "position_only" else "velocity_projection"
    )
    vehicle: VehicleKind = "fixed_wing" if vehicle_cfg.type.value == "fixed_wing" else "multirotor"
    turn: dict[str, float] = {}
    if vehicle == "fixed_wing":
        # The escape turn as Merlin's fixed-wing loops fly it: one model for the projection and the takeover
        # (merlin.core.geofence.fixed_wing_turn). Imported here: the core never depends on the autopilot.
        from merlin.autopilot import fixedwing_control as fc

        cp = fc.FixedWingControlParams()
        turn = {"full_bank_airspeed_mps": fc.full_bank_airspeed_mps(cp),
                "turn_airspeed_mps": fc.escape_airspeed_mps(cp),
                "turn_speed_gain_per_s": cp.speed_gain_per_s,
                "roll_rate_radps": cp.roll_sp_rate_radps,
                # the steepest bank the turns are flown at: the configuration's (an autopilot behind merlin
                # guard), or Merlin's own loops' limit; never shallower than the projection's own turn
                "turn_bank_max_rad": max(math.radians(vehicle_cfg.bank_max_deg) if vehicle_cfg.bank_max_deg
                                         is not None else fc.bank_limit_rad(cp),
                                         math.radians(vehicle_cfg.bank_limit_deg)),
                "recovery_height_m": recovery_height_m}
    return FenceParams(
        mode=mode,
        margin_m=geofence_cfg.margin_m,
        sigma_k=geofence_cfg.sigma_k,
        altitude_floor_m=geofence_cfg.altitude_floor_m,
        altitude_ceiling_m=geofence_cfg.altitude_ceiling_m,
        vehicle=vehicle,
        reaction_time_s=vehicle_cfg.reaction_time_s,
        max_h_decel_mps2=vehicle_cfg.max_horizontal_decel_mps2,
        max_v_decel_mps2=vehicle_cfg.max_vertical_decel_mps2,
        bank_limit_rad=math.radians(vehicle_cfg.bank_limit_deg),
        enabled=geofence_cfg.enabled,
        max_h_accel_mps2=STANDARD_GRAVITY_MPS2 * math.tan(math.radians(vehicle_cfg.max_tilt_deg)),
        max_v_accel_mps2=vehicle_cfg.max_vertical_accel_mps2,
        **turn,
    )


def _ring_ne(
    frame: LocalFrame, ring_deg: list[list[float]] | None, ring_ne: list[list[float]] | None
) -> list[PointNE]:
    if ring_deg is not None:
        lat = [v[0] for v in ring_deg]
        lon = [v[1] for v in ring_deg]
        north, east = frame.ne_from_latlon(lat, lon)
        pts = list(zip(north.tolist(), east.tolist(), strict=True))
    else:
        assert ring_ne is not None
        pts = [(float(v[0]), float(v[1])) for v in ring_ne]
    if len(pts) > 1 and pts[0] == pts[-1]:
        pts = pts[:-1]  # an explicitly closed ring
    return pts


def _where(frame: LocalFrame, at_ne_m: PointNE | None, in_degrees: bool) -> str:
    if at_ne_m is None:
        return ""
    n, e = at_ne_m
    local = f"north {n:.2f} m, east {e:.2f} m from home"
    if in_degrees:
        lat, lon, _ = frame.to_geodetic(n, e)
        return f" at lat {lat:.7f}, lon {lon:.7f} ({local})"
    return f" at {local}"


def _polygon(frame: LocalFrame, poly: FencePolygon, key: str, problems: list[str]) -> PolygonNE | None:
    shell = _ring_ne(frame, poly.vertices_deg, poly.vertices_ne_m)
    holes = [_ring_ne(frame, h, None) for h in poly.holes_deg]
    holes += [_ring_ne(frame, None, h) for h in poly.holes_ne_m]
    label = f"{key} ({poly.name!r})" if poly.name else key
    far = [p for ring in (shell, *holes) for p in ring if max(abs(p[0]), abs(p[1])) > MAX_ABS_POS_M]
    if far:
        problems.append(f"{label}: vertex {far[0]} m is more than {MAX_ABS_POS_M:.0f} m from home")
        return None
    problem = polygon_problem(shell, holes)
    if problem is not None:
        in_degrees = poly.vertices_deg is not None or bool(poly.holes_deg)
        problems.append(f"{label}: {problem.text}{_where(frame, problem.at_ne_m, in_degrees)}")
        return None
    return PolygonNE(tuple(shell), tuple(tuple(h) for h in holes))


def _circle(frame: LocalFrame, circle: FenceCircle, key: str, problems: list[str]) -> CircleNE | None:
    if circle.center_deg is not None:
        n, e, _ = frame.to_ned(circle.center_deg[0], circle.center_deg[1])
    else:
        assert circle.center_ne_m is not None
        n, e = float(circle.center_ne_m[0]), float(circle.center_ne_m[1])
    if not (math.isfinite(n) and math.isfinite(e)) or max(abs(n), abs(e)) > MAX_ABS_POS_M:
        label = f"{key} ({circle.name!r})" if circle.name else key
        problems.append(f"{label}: centre is more than {MAX_ABS_POS_M:.0f} m from home or not finite")
        return None
    return CircleNE((n, e), float(circle.radius_m))


def build_fence(
    geofence_cfg: GeofenceConfig,
    home_cfg: HomeConfig,
    vehicle_cfg: VehicleLimits,
    source: str = "<config>",
    *,
    grid_cells: int | None = None,
    recovery_height_m: float = 0.0,
) -> Fence:
    """The core fence, in the local frame about home. Raises :class:`ConfigError` naming bad geometry."""
    frame = LocalFrame(home_cfg.lat_deg, home_cfg.lon_deg, home_cfg.alt_amsl_m)
    problems: list[str] = []
    incl_p = [
        _polygon(frame, p, f"geofence.inclusion_polygons[{i}]", problems)
        for i, p in enumerate(geofence_cfg.inclusion_polygons)
    ]
    excl_p = [
        _polygon(frame, p, f"geofence.exclusion_polygons[{i}]", problems)
        for i, p in enumerate(geofence_cfg.exclusion_polygons)
    ]
    incl_c = [
        _circle(frame, c, f"geofence.inclusion_circles[{i}]", problems)
        for i, c in enumerate(geofence_cfg.inclusion_circles)
    ]
    excl_c = [
        _circle(frame, c, f"geofence.exclusion_circles[{i}]", problems)
        for i, c in enumerate(geofence_cfg.exclusion_circles)
    ]
    if problems:
        raise ConfigError(source, problems)
    params = build_fence_params(geofence_cfg, vehicle_cfg, recovery_height_m)
    kwargs = {} if grid_cells is None else {"grid_cells": grid_cells}
    try:
        return Fence(
            params,
            inclusion_polygons=tuple(p for p in incl_p if p is not None),
            inclusion_circles=tuple(c for c in incl_c if c is not None),
            exclusion_polygons=tuple(p for p in excl_p if p is not None),
            exclusion_circles=tuple(c for c in excl_c if c is not None),
            **kwargs,
        )
    except ValueError as exc:  # geometry the per-zone checks cannot see (e.g. exclusions cover everything)
        raise ConfigError(source, [f"geofence: {exc}"]) from None
