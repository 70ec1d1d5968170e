"""Cross-checks: settings that validate one by one but contradict each other, the range or the vehicle.

The models (:mod:`merlin.config.models`) check each key against its own bounds; a safety board also needs
to know that the keys agree: that home is inside the range, that the braking the fence projection counts on
is one the vehicle can deliver, that the take-off and RTL heights lie between the floor and the ceiling,
and so on. Each check here has a stable id (``XC001``) and a slug (``home-outside-inclusion``), a severity
and, for every finding, the configuration keys and the numbers involved. One registry serves every tool:
``merlin check-config`` and ``merlin review`` print the findings, ``merlin sim`` and ``merlin serve`` run
them at load time and refuse to fly on an error unless the operator accepts that very check by id
(``--accept-risk XC004``), which is then recorded in the run's summary or log (:func:`gate`).

Severities: ``error`` -- the configuration cannot deliver what it promises (the fence cannot stop the
vehicle where it says, the vehicle cannot take off or return, the check's premise is physically false);
``warning`` -- a setting a reviewer should look at and can justify.

Adding a check (docs/crosschecks.md says the same): write a function of one :class:`CheckInput` that
yields :class:`Finding` values built with its ``make`` helper, decorate it with :func:`cross_check`
giving the next free id (ids are never reused or renumbered: logs and overrides name them), a slug, the
severity and a one-line summary, and add it to :data:`CHECKS`. ``tests/config/test_crosschecks.py``
checks that ids and slugs are unique and every check is documented in ``docs/crosschecks.md``; give the
check a unit test with a configuration that trips it and one that does not.

The vehicle's capability (:class:`VehicleCapability`) comes from the simulator's vehicle file when one is
known (``sims.runner.vehicle_capability``): the deceleration the fence projection assumes must not exceed what the
thrust, the mass and the tilt limit can hold.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import shapely

from merlin.config.loader import ConfigError
from merlin.config.models import MerlinConfig
from merlin.core.geofence import Fence, circle_polygon_ne, trigger_distance_m

GRAVITY_MPS2 = 9.80665


class Severity(StrEnum):
    ERROR = "error"
    WARNING = "warning"


@dataclass(frozen=True, slots=True)
class Finding:
    """One finding of one check: what is wrong, in numbers, and the keys to change."""

    check_id: str
    slug: str
    severity: Severity
    keys: tuple[str, ...]
    numbers: tuple[tuple[str, float], ...]
    text: str

    @property
    def label(self) -> str:
        return f"{self.check_id} {self.slug}"

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.check_id, "slug": self.slug, "severity": self.severity.value, "keys": list(self.keys),
                "numbers": {k: v for k, v in self.numbers}, "text": self.text}

    def line(self) -> str:
        return f"{self.severity.value.upper()} {self.label}: {self.text} [{', '.join(self.keys)}]"


@dataclass(frozen=True, slots=True)
class VehicleCapability:
    """What the vehicle can deliver, derived from its model (:func:`multirotor_capability`)."""

    source: str
    max_h_decel_mps2: float  # horizontal deceleration holdable at constant height
    max_v_decel_mps2: float  # vertical deceleration holdable both ways (braking a climb and a descent)
    tilt_limit_deg: float  # the attitude controller's tilt limit, or the thrust's, whichever is lower
    lag_s: float  # the motors' and the attitude loop's time constants together
    tilt_rate_radps: float  # the attitude loop's roll/pitch rate limit
    derivation: str  # the numbers behind the figures, one line, for the reviewer

    def min_reaction_s(self, decel_mps2: float) -> float:
        """The least time from a braking command to braking at ``decel_mps2``: the loops' lag and the tilt
        from level to the braking attitude at the rate limit (a lower bound: a vehicle tilted forward at
        speed has farther to swing)."""
        return self.lag_s + math.atan(decel_mps2 / GRAVITY_MPS2) / self.tilt_rate_radps


@dataclass(frozen=True, slots=True)
class CheckInput:
    """What a check reads: the configuration, its fence as built (None: fence disabled) and the vehicle's
    capability (None: no vehicle model known, e.g. a fixed wing or check-config without ``--vehicle``)."""

    cfg: MerlinConfig
    fence: Fence | None
    vehicle: VehicleCapability | None
    #: the trusted core's tick period where the driver is known (``merlin sim``, ``merlin serve``), 0 where
    #: not (``check-config``): a limit crossed just after a tick is seen up to one period late
    core_period_s: float = 0.0


@dataclass(frozen=True, slots=True)
class CrossCheck:
    check_id: str
    slug: str
    severity: Severity
    summary: str
    run: Callable[[CheckInput, CrossCheck], Iterable[Finding]]

    def make(self, keys: Sequence[str], numbers: dict[str, float], text: str) -> Finding:
        return Finding(self.check_id, self.slug, self.severity, tuple(keys),
                       tuple((k, float(v)) for k, v in numbers.items()), text)


def cross_check(check_id: str, slug: str, severity: Severity, summary: str
                ) -> Callable[[Callable[[CheckInput, CrossCheck], Iterable[Finding]]], CrossCheck]:
    """Decorator: the function becomes a :class:`CrossCheck` (list it in :data:`CHECKS`)."""

    def wrap(fn: Callable[[CheckInput, CrossCheck], Iterable[Finding]]) -> CrossCheck:
        return CrossCheck(check_id, slug, severity, summary, fn)

    return wrap


# ------------------------------------------------------------------------------------ vehicle capability


def multirotor_capability(mass_kg: float, max_thrust_n: float, motor_time_constant_s: float, source: str,
                          gains: Any = None) -> VehicleCapability:
    """The braking and reaction a multirotor with these figures can deliver under Merlin's inner loops.

    Horizontal: ``g tan(tilt)`` at constant height, with ``tilt`` the lower of the controller's tilt limit and
    the tilt at which the usable thrust (``thrust_max`` share of the maximum) still carries the weight, and
    no more than the velocity loop's acceleration limit. Vertical: the lower of braking a descent (usable
    thrust over weight, less g) and braking a climb (g less the minimum collective's thrust), each no more
    than the loop's vertical acceleration limit. Reaction: the motors' time constant, the attitude loop's
    (1 / its P gain) and the time to tilt to the braking attitude at the rate limit -- a lower bound of
    what the projection's ``reaction_time_s`` must cover (``docs/crosschecks.md``)."""
    from merlin.autopilot.multirotor_control import DEFAULT_GAINS

    k = gains if gains is not None else DEFAULT_GAINS
    g = GRAVITY_MPS2
    usable_n = k.thrust_max * max_thrust_n
    weight_n = mass_kg * g
    tilt_thrust = math.acos(min(1.0, weight_n / usable_n)) if usable_n > 0 else 0.0
    tilt = min(k.tilt_max_rad, tilt_thrust)
    a_h = min(g * math.tan(tilt), k.acc_max_xy_mps2)
    up = min(usable_n / mass_kg - g, k.acc_max_up_mps2)  # braking a descent
    down = min(g - k.thrust_min * max_thrust_n / mass_kg, k.acc_max_down_mps2)  # braking a climb
    a_v = max(0.0, min(up, down))
    lag = motor_time_constant_s + 1.0 / k.att_p_rp_per_s
    derivation = (f"mass {mass_kg:g} kg, max thrust {max_thrust_n:.1f} N (usable {k.thrust_max:g} x), tilt limit "
                  f"{math.degrees(k.tilt_max_rad):.0f} deg (thrust allows {math.degrees(tilt_thrust):.0f} deg): "
                  f"horizontal g tan({math.degrees(tilt):.0f} deg) = {g * math.tan(tilt):.2f} m/s^2, loop limit "
                  f"{k.acc_max_xy_mps2:g}; vertical up {usable_n / mass_kg - g:.2f} (loop {k.acc_max_up_mps2:g}), "
                  f"down {g - k.thrust_min * max_thrust_n / mass_kg:.2f} (loop {k.acc_max_down_mps2:g}); reaction: "
                  f"motor {motor_time_constant_s:g} s + attitude 1/{k.att_p_rp_per_s:g} s + the braking tilt at "
                  f"{math.degrees(k.rate_max_rp_radps):.0f} deg/s")
    return VehicleCapability(source, a_h, a_v, math.degrees(tilt), lag, k.rate_max_rp_radps, derivation)


# ------------------------------------------------------------------------------------------- the checks


def _stage_key(cfg: MerlinConfig, p: str) -> str:
    return f"envelope.stages.{cfg.envelope.active_stage}.{p}"


def _zones(fence: Fence) -> tuple[Any, Any]:
    """(inclusion union or None, exclusion union or None) as the core enforces them (circles inscribed in
    inclusion zones, circumscribed about keep-outs)."""
    inc = [shapely.Polygon(p.shell_ne_m, list(p.holes_ne_m)) for p in fence.inclusion_polygons]
    inc += [shapely.Polygon(circle_polygon_ne(c, circumscribed=False)) for c in fence.inclusion_circles]
    exc = [shapely.Polygon(p.shell_ne_m, list(p.holes_ne_m)) for p in fence.exclusion_polygons]
    exc += [shapely.Polygon(circle_polygon_ne(c, circumscribed=True)) for c in fence.exclusion_circles]
    return (shapely.union_all(inc) if inc else None), (shapely.union_all(exc) if exc else None)


_HOME = shapely.Point(0.0, 0.0)


@cross_check("XC001", "home-outside-inclusion", Severity.ERROR,
             "home (the origin of the local frame, where RTL returns) lies outside every inclusion zone")
def _home_outside_inclusion(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    if inp.fence is None:
        return
    inc, _ = _zones(inp.fence)
    if inc is not None and not inc.covers(_HOME):
        d = float(shapely.distance(_HOME, inc))
        yield c.make(("home", "geofence.inclusion_polygons", "geofence.inclusion_circles"), {"distance_m": d},
                     f"home is {d:.1f} m outside the inclusion zones: arming is refused there and RTL returns "
                     "to a point outside the range")


@cross_check("XC002", "home-inside-keep-out", Severity.ERROR, "home lies inside a keep-out (exclusion) zone")
def _home_inside_keep_out(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    if inp.fence is None:
        return
    _, exc = _zones(inp.fence)
    if exc is not None and exc.covers(_HOME):
        d = float(shapely.distance(_HOME, exc.boundary))
        yield c.make(("home", "geofence.exclusion_polygons", "geofence.exclusion_circles"), {"depth_m": d},
                     f"home is {d:.1f} m inside a keep-out zone: arming is refused there and RTL lands in it")


def _multirotor_capability(inp: CheckInput) -> VehicleCapability | None:
    """The vehicle's derived capability where the capability checks apply: a multirotor whose airframe is
    known (the capability model is a multirotor's: thrust, mass, tilt limit)."""
    return inp.vehicle if inp.vehicle is not None and inp.cfg.vehicle.type.value == "multirotor" else None


def _decel_beyond(c: CrossCheck, cap: VehicleCapability, axis: str, configured: float, capable: float,
                  assumes: str, consequence: str = "") -> Iterator[Finding]:
    """The finding of a configured braking (``vehicle.max_<axis>_decel_mps2``) above what the vehicle holds."""
    if configured > capable + 1e-9:
        yield c.make((f"vehicle.max_{axis}_decel_mps2",), {"configured_mps2": configured, "vehicle_mps2": capable},
                     f"{assumes.format(configured)}, the vehicle {cap.source} can hold {capable:.2f} m/s^2 "
                     f"({cap.derivation}){consequence}")


@cross_check("XC003", "horizontal-decel-beyond-vehicle", Severity.ERROR,
             "the fence projection brakes harder than the vehicle can (thrust, mass, tilt limit)")
def _h_decel(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    cap = _multirotor_capability(inp)
    if cap is not None:
        yield from _decel_beyond(c, cap, "horizontal", inp.cfg.vehicle.max_horizontal_decel_mps2,
                                 cap.max_h_decel_mps2, "the fence projection assumes {:g} m/s^2 of braking",
                                 ": it stops later than projected and breaches")


@cross_check("XC004", "vertical-decel-beyond-vehicle", Severity.ERROR,
             "the ceiling/floor projection brakes a climb or descent harder than the vehicle can")
def _v_decel(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    cap = _multirotor_capability(inp)
    if cap is not None:
        yield from _decel_beyond(c, cap, "vertical", inp.cfg.vehicle.max_vertical_decel_mps2,
                                 cap.max_v_decel_mps2,
                                 "the ceiling and floor projections assume {:g} m/s^2 of vertical braking")


@cross_check("XC005", "reaction-time-below-vehicle", Severity.ERROR,
             "the projection's reaction time is shorter than the vehicle's loops can react")
def _reaction(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    v, cap = inp.cfg.vehicle, _multirotor_capability(inp)
    if cap is None:
        return
    if v.max_horizontal_decel_mps2 > cap.max_h_decel_mps2 + 1e-9:
        return  # no reaction time delivers a braking the vehicle cannot hold: XC003 says so
    need = cap.min_reaction_s(v.max_horizontal_decel_mps2) + inp.core_period_s
    if v.reaction_time_s + 1e-9 < need:
        core = (f" and the trusted core's {inp.core_period_s * 1e3:g} ms tick, which may see the crossing one tick "
                "late," if inp.core_period_s > 0.0 else "")
        yield c.make(("vehicle.reaction_time_s", "vehicle.max_horizontal_decel_mps2"),
                     {"configured_s": v.reaction_time_s, "vehicle_s": need, "core_period_s": inp.core_period_s},
                     f"the fence projection allows {v.reaction_time_s:g} s from detection to braking at "
                     f"{v.max_horizontal_decel_mps2:g} m/s^2; the vehicle {cap.source}{core} needs at least "
                     f"{need:.3f} s ({cap.derivation})")


@cross_check("XC006", "sigma-k-zero", Severity.ERROR,
             "the fence ignores the navigation's position uncertainty (sigma_k 0) while navigation can degrade")
def _sigma_k(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    g, n = inp.cfg.geofence, inp.cfg.nav
    if not g.enabled or g.sigma_k > 0.0:
        return
    yield c.make(("geofence.sigma_k", "nav.max_pos_sigma_h_m", "nav.inertial_time_limit_s"),
                 {"sigma_k": g.sigma_k, "max_pos_sigma_h_m": n.max_pos_sigma_h_m,
                  "inertial_time_limit_s": n.inertial_time_limit_s},
                 f"sigma_k is 0: the fence keeps only margin_m {g.margin_m:g} m clear whatever the position "
                 f"uncertainty, while grants are allowed up to sigma_h {n.max_pos_sigma_h_m:g} m and inertial-only "
                 f"navigation is flown for up to {n.inertial_time_limit_s:g} s")


def _altitude_band(inp: CheckInput) -> tuple[float | None, float | None]:
    """(lowest, highest) height the fence lets the vehicle hold at rest: floor + margin + the floor's
    hysteresis, ceiling - margin (None: no such limit, or the fence disabled)."""
    from merlin.core.geofence import FLOOR_CLEAR_HYSTERESIS_M

    g = inp.cfg.geofence
    if not g.enabled:
        return None, None
    margin = g.margin_m if g.mode.value == "velocity_projection" else 0.0
    lo = None if g.altitude_floor_m is None else g.altitude_floor_m + margin + FLOOR_CLEAR_HYSTERESIS_M
    hi = None if g.altitude_ceiling_m is None else g.altitude_ceiling_m - margin
    return lo, hi


def _height_outside_band(inp: CheckInput, c: CrossCheck, what: str, ceiling: bool, text: str) -> Iterator[Finding]:
    """The finding of the trusted ``<what>_altitude_m`` (take-off or RTL) at or above the fence's highest
    height (``ceiling``) or at or below its lowest; ``text`` formats ``{h}`` (the height) and ``{limit}``."""
    lo, hi = _altitude_band(inp)
    h, limit = getattr(inp.cfg.trusted, f"{what}_altitude_m"), (hi if ceiling else lo)
    if limit is not None and (h >= limit if ceiling else h <= limit):
        side = "ceiling" if ceiling else "floor"
        yield c.make((f"trusted.{what}_altitude_m", f"geofence.altitude_{side}_m", "geofence.margin_m"),
                     {f"{what}_m": h, "highest_m" if ceiling else "lowest_m": limit}, text.format(h=h, limit=limit))


@cross_check("XC007", "takeoff-above-ceiling", Severity.ERROR,
             "the take-off height is at or above the fence ceiling less its margin")
def _takeoff_ceiling(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    return _height_outside_band(inp, c, "takeoff", True,
                                "take-off climbs to {h:g} m, but the ceiling trips at {limit:g} m (ceiling less "
                                "margin): every take-off ends in the fence's action")


@cross_check("XC008", "takeoff-below-floor", Severity.ERROR,
             "the take-off height does not clear the fence floor (floor + margin + hysteresis)")
def _takeoff_floor(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    return _height_outside_band(inp, c, "takeoff", False,
                                "take-off stops at {h:g} m, below {limit:g} m (floor + margin + 1 m): the floor "
                                "never starts to apply and every grant is refused until the vehicle is clear of it")


@cross_check("XC009", "rtl-above-ceiling", Severity.ERROR, "the RTL height is at or above the ceiling less its margin")
def _rtl_ceiling(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    return _height_outside_band(inp, c, "rtl", True,
                                "RTL climbs to {h:g} m, but the ceiling trips at {limit:g} m (ceiling less margin)")


@cross_check("XC010", "rtl-below-floor", Severity.ERROR, "the RTL height is within the fence floor's margin")
def _rtl_floor(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    return _height_outside_band(inp, c, "rtl", False,
                                "RTL returns at {h:g} m, below {limit:g} m (floor + margin + 1 m): the return "
                                "flies inside the floor's margin")


@cross_check("XC011", "blend-longer-than-reaction", Severity.WARNING,
             "the hand-over blend is longer than the reaction time the fence projection allows")
def _blend(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    b, r = inp.cfg.handover.blend_window_s, inp.cfg.vehicle.reaction_time_s
    if b > r + 1e-9:
        yield c.make(("handover.blend_window_s", "vehicle.reaction_time_s"), {"blend_s": b, "reaction_s": r},
                     f"a hand-over blends the command over {b:g} s, longer than the {r:g} s the fence projection "
                     "allows from detection to full braking: a take-over by the operator reaches full authority "
                     "only after the blend")


def _clamp_speed(cfg: MerlinConfig) -> tuple[float, str]:
    """The horizontal speed an experimental velocity setpoint is clamped to (as PX4 clamps offboard setpoints
    to MPC_XY_VEL_MAX), and its key."""
    return cfg.vehicle.max_speed_h_mps, "vehicle.max_speed_h_mps"


@cross_check("XC012", "margin-below-timeout-distance", Severity.WARNING,
             "the fence margin is shorter than the distance flown at full speed during the controller timeouts")
def _margin_timeouts(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    cfg = inp.cfg
    g, w = cfg.geofence, cfg.watchdogs
    if not g.enabled:
        return
    vmax, vkey = _clamp_speed(cfg)
    for wd in ("controller_heartbeat", "setpoint_stale"):
        timeout = getattr(w, wd).timeout_s
        d = vmax * timeout
        if g.margin_m < d:
            yield c.make(("geofence.margin_m", f"watchdogs.{wd}.timeout_s", vkey),
                         {"margin_m": g.margin_m, "distance_m": d, "speed_mps": vmax, "timeout_s": timeout},
                         f"fence margin {g.margin_m:g} m is smaller than the {d:.1f} m covered at the maximum "
                         f"speed {vmax:g} m/s during the {wd} timeout of {timeout:g} s")


@cross_check("XC013", "velocity-limit-above-clamp", Severity.WARNING,
             "an envelope velocity limit lies beyond the speed a velocity setpoint may command")
def _vel_above_clamp(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    cfg = inp.cfg
    env = cfg.envelope.effective()
    vmax, vkey = _clamp_speed(cfg)
    for p in ("vel_n_mps", "vel_e_mps"):
        lim = env[p]
        if lim.enabled and min(abs(lim.min), abs(lim.max)) > vmax:
            yield c.make((_stage_key(cfg, p), vkey), {"limit_mps": min(abs(lim.min), abs(lim.max)), "speed_mps": vmax},
                         f"the {p} limits [{lim.min:g}, {lim.max:g}] lie beyond the {vmax:g} m/s velocity setpoints "
                         f"are clamped to ({vkey}): only attitude setpoints, wind or a failing vehicle reach them, "
                         "so they bound those alone")


@cross_check("XC014", "geofence-disabled", Severity.WARNING, "the geofence is disabled")
def _fence_off(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    if not inp.cfg.geofence.enabled:
        yield c.make(("geofence.enabled",), {}, "the geofence is disabled: nothing keeps the vehicle on the range")


def _home_to_boundary_m(fence: Fence | None) -> float | None:
    if fence is None or fence.allowed_area is None:
        return None
    return float(shapely.distance(_HOME, shapely.boundary(fence.allowed_area)))


@cross_check("XC015", "duration-longer-than-time-to-fence", Severity.WARNING,
             "a velocity or altitude exceedance duration outlasts the flight from home to the fence")
def _duration_reach(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    cfg = inp.cfg
    reach = _home_to_boundary_m(inp.fence)
    if reach is None:
        return
    vmax = cfg.vehicle.max_speed_h_mps
    t_reach = reach / vmax
    env = cfg.envelope.effective()
    for p in ("vel_n_mps", "vel_e_mps", "altitude_m"):
        lim = env[p]
        if lim.enabled and lim.duration_s > t_reach:
            yield c.make((f"{_stage_key(cfg, p)}.duration_s", "vehicle.max_speed_h_mps"),
                         {"duration_s": lim.duration_s, "time_to_fence_s": t_reach, "distance_m": reach},
                         f"{p} exceedance duration {lim.duration_s:g} s is longer than the {t_reach:.1f} s the "
                         f"vehicle needs at {vmax:g} m/s to reach the fence {reach:.1f} m from home")


@cross_check("XC016", "full-speed-trips-at-home", Severity.WARNING,
             "at full speed head-on the fence trips farther out than home is from the boundary")
def _trip_from_home(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    reach = _home_to_boundary_m(inp.fence)
    if reach is None or inp.fence is None:
        return
    vmax = inp.cfg.vehicle.max_speed_h_mps
    d0 = trigger_distance_m(inp.fence.params, vmax, 0.0)
    if d0 >= reach:
        yield c.make(("geofence.margin_m", "vehicle.max_speed_h_mps"), {"trip_distance_m": d0, "home_to_fence_m": reach},
                     f"at {vmax:g} m/s head-on the fence trips {d0:.1f} m from the boundary, but home is only "
                     f"{reach:.1f} m from it: a flight at full speed is revoked from anywhere")


@cross_check("XC017", "takeoff-below-envelope", Severity.WARNING,
             "the take-off height is below the envelope's altitude minimum")
def _takeoff_env(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    cfg = inp.cfg
    alt = cfg.envelope.effective()["altitude_m"]
    t = cfg.trusted.takeoff_altitude_m
    if alt.enabled and t < alt.min:
        yield c.make((f"{_stage_key(cfg, 'altitude_m')}.min", "trusted.takeoff_altitude_m"),
                     {"takeoff_m": t, "envelope_min_m": alt.min},
                     f"take-off altitude {t:g} m is below the envelope minimum {alt.min:g} m: a grant right after "
                     "take-off violates the envelope at once")


@cross_check("XC018", "envelope-altitude-above-ceiling", Severity.WARNING,
             "the envelope's altitude maximum lies above the fence ceiling")
def _env_ceiling(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    cfg = inp.cfg
    g = cfg.geofence
    alt = cfg.envelope.effective()["altitude_m"]
    if alt.enabled and g.enabled and g.altitude_ceiling_m is not None and alt.max > g.altitude_ceiling_m:
        yield c.make((f"{_stage_key(cfg, 'altitude_m')}.max", "geofence.altitude_ceiling_m"),
                     {"envelope_max_m": alt.max, "ceiling_m": g.altitude_ceiling_m},
                     f"envelope altitude maximum {alt.max:g} m is above the fence ceiling {g.altitude_ceiling_m:g} m: "
                     "the fence trips before the envelope limit is reached")


@cross_check("XC019", "operator-stick-beyond-envelope", Severity.WARNING,
             "full stick commands a speed beyond the envelope limits that oversee the operator")
def _stick(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    cfg = inp.cfg
    o = cfg.operator
    if not o.oversight_envelope:
        return
    env = cfg.envelope.effective()
    for p in ("vel_n_mps", "vel_e_mps"):
        lim = env[p]
        if lim.enabled and o.max_speed_h_mps > min(abs(lim.min), abs(lim.max)):
            yield c.make((_stage_key(cfg, p), "operator.max_speed_h_mps"),
                         {"stick_mps": o.max_speed_h_mps, "limit_mps": min(abs(lim.min), abs(lim.max))},
                         f"full stick ({o.max_speed_h_mps:g} m/s) exceeds the {p} limits [{lim.min:g}, {lim.max:g}] "
                         "that oversee the operator")


@cross_check("XC020", "cooldown-below-heartbeat-timeout", Severity.WARNING,
             "the re-grant cool-down is shorter than the heartbeat timeout")
def _cooldown(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    cfg = inp.cfg
    hb, to = cfg.handover.cooldown_s, cfg.watchdogs.controller_heartbeat.timeout_s
    if hb < to:
        yield c.make(("handover.cooldown_s", "watchdogs.controller_heartbeat.timeout_s"),
                     {"cooldown_s": hb, "timeout_s": to},
                     f"cool-down {hb:g} s is shorter than the heartbeat timeout {to:g} s: a flapping controller can "
                     "be re-granted at once")


@cross_check("XC021", "attitude-limit-above-clamp", Severity.WARNING,
             "an envelope roll or pitch limit lies beyond the tilt attitude setpoints are clamped to")
def _att_above_clamp(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    cfg = inp.cfg
    if cfg.vehicle.type.value != "multirotor":
        return
    env = cfg.envelope.effective()
    tilt = cfg.vehicle.max_tilt_deg
    for p in ("roll_deg", "pitch_deg"):
        lim = env[p]
        if lim.enabled and min(abs(lim.min), abs(lim.max)) > tilt:
            yield c.make((_stage_key(cfg, p), "vehicle.max_tilt_deg"),
                         {"limit_deg": min(abs(lim.min), abs(lim.max)), "tilt_deg": tilt},
                         f"the {p} limits [{lim.min:g}, {lim.max:g}] lie beyond the {tilt:g} deg attitude setpoints "
                         "are clamped to (vehicle.max_tilt_deg): no setpoint reaches them, only a disturbance or a "
                         "failing vehicle")


@cross_check("XC022", "no-safe-return-path", Severity.ERROR,
             "from part of the range no route home keeps the fence's margin from the keep-outs and the boundary")
def _return_path(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    fence = inp.fence
    if fence is None or inp.cfg.vehicle.type != "multirotor":
        return  # the fixed wing's routes keep a turn radius more: its own analysis (docs/fixed-wing.md)
    from merlin.autopilot import guidance, route

    # the clearance RTL's route keeps with a perfect position (with position uncertainty it keeps more)
    clearance = fence.params.margin_m + guidance.ROUTE_MARGIN_M
    r = route.home_reachability(fence, clearance, REACHABILITY_SPACING_M)
    if r.unreachable == 0:
        return
    assert r.worst_ne_m is not None
    n, e = r.worst_ne_m
    yield c.make(
        ("geofence.inclusion_polygons", "geofence.exclusion_polygons", "geofence.exclusion_circles",
         "geofence.margin_m", "trusted.no_route_fallback"),
        {"unreachable_fraction": r.unreachable_fraction, "worst_north_m": n, "worst_east_m": e,
         "clearance_m": clearance, "spacing_m": r.spacing_m},
        f"{100.0 * r.unreachable_fraction:.1f} % of the range (sampled every {r.spacing_m:g} m) has no route home"
        f" that keeps {clearance:.1f} m from the keep-outs and the boundary, e.g. from ({n:.0f}, {e:.0f}) m"
        f" north/east of home: RTL from there flies trusted.no_route_fallback"
        f" ({inp.cfg.trusted.no_route_fallback}) instead of returning",
    )


@cross_check("XC023", "mission-leaves-range", Severity.ERROR,
             "a trusted mission waypoint or leg lies within the fence's margin of a keep-out or the boundary")
def _mission_in_range(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    fence, wps = inp.fence, inp.cfg.trusted.mission_ned_m
    if fence is None or not wps:
        return
    from merlin.autopilot import route

    if not route.has_zones(fence):
        return
    margin = fence.params.margin_m
    pts = [(0.0, 0.0)] + [(float(w[0]), float(w[1])) for w in wps]  # the mission starts over home
    for i in range(1, len(pts)):
        a, b = pts[i - 1], pts[i]
        leg = shapely.LineString([a, b]) if a != b else shapely.Point(b)
        worst = min(route.hazard_distance_m(fence, a), route.hazard_distance_m(fence, b))
        for hz in (fence.exclusion_area, shapely.boundary(fence.allowed_area) if fence.has_inclusion else None):
            if hz is not None:
                worst = min(worst, float(shapely.distance(hz, leg)))
        if fence.has_inclusion and not shapely.covers(fence.allowed_area, leg):
            worst = min(worst, -float(shapely.length(shapely.difference(leg, fence.allowed_area))))
        if worst < margin:
            yield c.make(
                ("trusted.mission_ned_m", "geofence.margin_m"),
                {"waypoint": float(i - 1), "clearance_m": worst, "margin_m": margin},
                f"the leg to mission waypoint {i - 1} ({b[0]:.0f}, {b[1]:.0f}) m comes {worst:.1f} m from a"
                f" keep-out or the boundary (negative: through it), within the fence's {margin:g} m margin: the"
                " fence trips on the trusted mission and RTL takes over",
            )


@cross_check("XC024", "clamp-above-envelope", Severity.WARNING,
             "a speed or turn rate Merlin flies an experimental position or yaw setpoint at lies beyond the envelope")
def _clamp_above_env(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    """Merlin's trusted loops choose the speed of a position setpoint (the horizontal cruise speed within the
    horizontal clamp, the climb and descent clamps) and the rate a yaw setpoint is turned at: if one lies
    beyond the envelope, a legitimate setpoint is revoked for Merlin's own choice. An explicit velocity
    setpoint beyond the envelope is the controller's and is revoked as it should be (XC013 is the reverse)."""
    cfg = inp.cfg
    if cfg.vehicle.type.value != "multirotor":
        return
    env = cfg.envelope.effective()
    v = cfg.vehicle
    h = min(v.max_speed_h_mps, cfg.trusted.cruise_speed_mps)
    hkeys = ("vehicle.max_speed_h_mps", "trusted.cruise_speed_mps")
    rows: list[tuple[str, float, float, tuple[str, ...], str]] = [
        ("vel_n_mps", h, min(abs(env["vel_n_mps"].min), env["vel_n_mps"].max), hkeys, "horizontal speed"),
        ("vel_e_mps", h, min(abs(env["vel_e_mps"].min), env["vel_e_mps"].max), hkeys, "horizontal speed"),
        ("vel_d_mps", v.max_speed_up_mps, -env["vel_d_mps"].min, ("vehicle.max_speed_up_mps",), "climb rate"),
        ("vel_d_mps", v.max_speed_down_mps, env["vel_d_mps"].max, ("vehicle.max_speed_down_mps",), "descent rate"),
        ("yaw_rate_degps", v.max_yaw_rate_degps, min(abs(env["yaw_rate_degps"].min), env["yaw_rate_degps"].max),
         ("vehicle.max_yaw_rate_degps",), "yaw rate"),
    ]
    for p, flown, limit, keys, what in rows:
        if env[p].enabled and flown > limit + 1e-9:
            yield c.make((_stage_key(cfg, p), *keys), {"flown": flown, "limit": limit},
                         f"Merlin flies an experimental setpoint at a {what} of {flown:g} ({', '.join(keys)}), "
                         f"beyond the envelope's {p} limit {limit:g}: a setpoint the controller may legitimately "
                         "send is revoked for the speed Merlin chose to fly it at")


def _grant_heights(cfg: MerlinConfig) -> tuple[float | None, float | None]:
    """(enforced, derived) minimum grant heights: what the arbiter refuses below
    (:func:`merlin.config.runtime.min_grant_height_m`), and, for a fixed wing, the height the stall recovery's
    bound derives (None for a multirotor)."""
    from merlin.config.runtime import min_grant_height_m

    derived = None
    if cfg.vehicle.type.value == "fixed_wing":
        from merlin.autopilot import fixedwing_recovery

        derived = fixedwing_recovery.min_grant_height_m(cfg)
    return min_grant_height_m(cfg), derived


@cross_check("XC025", "grant-below-recovery-height", Severity.WARNING,
             "a fixed wing may be granted below the height from which its stall recovery keeps the floor")
def _grant_below_recovery(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    """``handover.min_grant_height_m`` set below the derived minimum grant height (the floor, or the envelope's
    altitude minimum, plus the recovery's height bound): a revocation just after such a grant may take the
    aircraft through the floor. A warning, not an error: a test range may choose it (the recovery scenarios
    ``fw_adv_push_before_stall_38m`` and ``_45m`` fly a configuration that does, to measure the recovery)."""
    enforced, derived = _grant_heights(inp.cfg)
    if derived is None or enforced is None or enforced >= derived - 1e-9:
        return
    yield c.make(("handover.min_grant_height_m", "geofence.altitude_floor_m", "geofence.margin_m",
                  _stage_key(inp.cfg, "altitude_m")),
                 {"min_grant_height_m": enforced, "derived_m": derived},
                 f"grants are allowed from {enforced:g} m, below the {derived:.1f} m from which the stall recovery "
                 "keeps the floor (floor + margin + the recovery's height bound, merlin.autopilot.fixedwing_recovery): "
                 "a revocation just after a grant there may go through the floor")


@cross_check("XC026", "no-grant-height", Severity.ERROR,
             "the minimum grant height is at or above the ceiling or the envelope's altitude maximum")
def _no_grant_height(inp: CheckInput, c: CrossCheck) -> Iterator[Finding]:
    """No height is left at which a grant is allowed and the vehicle may fly: every request is refused."""
    enforced, _derived = _grant_heights(inp.cfg)
    if enforced is None:
        return
    _, hi = _altitude_band(inp)
    alt = inp.cfg.envelope.effective().get("altitude_m")
    tops: list[tuple[float | None, str, tuple[str, ...]]] = [
        (hi, "the fence ceiling less its margin", ("geofence.altitude_ceiling_m", "geofence.margin_m"))]
    if alt is not None and alt.enabled:
        tops.append((alt.max, "the envelope's altitude maximum", (_stage_key(inp.cfg, "altitude_m"),)))
    for top, what, keys in tops:
        if top is not None and enforced >= top:
            yield c.make(("handover.min_grant_height_m", *keys), {"min_grant_height_m": enforced, "highest_m": top},
                         f"no grant is allowed below {enforced:.1f} m, and {what} is {top:g} m: every request for "
                         "authority is refused")


#: Grid spacing of the range's sample points for XC022, m.
REACHABILITY_SPACING_M = 10.0


#: Every check, in id order. Add a new one here (module docstring: "Adding a check").
CHECKS: tuple[CrossCheck, ...] = (
    _home_outside_inclusion,
    _home_inside_keep_out,
    _h_decel,
    _v_decel,
    _reaction,
    _sigma_k,
    _takeoff_ceiling,
    _takeoff_floor,
    _rtl_ceiling,
    _rtl_floor,
    _blend,
    _margin_timeouts,
    _vel_above_clamp,
    _fence_off,
    _duration_reach,
    _trip_from_home,
    _takeoff_env,
    _env_ceiling,
    _stick,
    _cooldown,
    _att_above_clamp,
    _return_path,
    _mission_in_range,
    _clamp_above_env,
    _grant_below_recovery,
    _no_grant_height,
)


def check_ids() -> dict[str, CrossCheck]:
    return {c.check_id: c for c in CHECKS}


# ------------------------------------------------------------------------------------------ running them


def run_checks(cfg: MerlinConfig, fence: Fence | None = None, vehicle: VehicleCapability | None = None,
               *, build: bool = True, core_period_s: float = 0.0) -> list[Finding]:
    """Every check's findings, errors first, then in id order. ``fence``: the configuration's fence as built
    (built here when None and ``build``; the fence is None when the configuration disables it);
    ``core_period_s``: the trusted core's tick period, where the driver that will fly it is known."""
    if fence is None and build and cfg.geofence.enabled:
        from merlin.config.fence_build import build_fence

        fence = build_fence(cfg.geofence, cfg.home, cfg.vehicle)
    inp = CheckInput(cfg, fence, vehicle, core_period_s)
    out = [f for chk in CHECKS for f in chk.run(inp, chk)]
    return sorted(out, key=lambda f: (f.severity is not Severity.ERROR, f.check_id))


class CrossCheckRefusal(ConfigError):
    """A configuration with an error-severity finding that was not accepted: ``merlin sim`` and ``merlin
    serve`` refuse to fly it (exit 2, like any input they refuse, the message naming each check)."""

    def __init__(self, source: str, blocking: Sequence[Finding]) -> None:
        self.blocking = tuple(blocking)
        ids = ",".join(f.check_id for f in blocking)
        problems = [f"refused to fly: {f.line()}" for f in blocking]
        problems.append(f"to fly anyway, accept each risk by id (it is recorded): --accept-risk {ids}")
        super().__init__(source, problems)


@dataclass(frozen=True, slots=True)
class GateResult:
    findings: tuple[Finding, ...]
    accepted: tuple[Finding, ...]  # errors flown anyway by an explicit --accept-risk
    warnings: tuple[Finding, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"accepted": [f.to_dict() for f in self.accepted], "warnings": [f.to_dict() for f in self.warnings],
                "errors": [f.to_dict() for f in self.findings if f.severity is Severity.ERROR]}


def parse_accept(values: Sequence[str] | None, source: str = "--accept-risk") -> frozenset[str]:
    """Check ids from ``--accept-risk`` values (repeatable, comma-separated); unknown ids are an error."""
    ids: set[str] = set()
    for v in values or ():
        ids.update(x.strip().upper() for x in str(v).split(",") if x.strip())
    known = check_ids()
    bad = sorted(i for i in ids if i not in known)
    if bad:
        raise ConfigError(source, [f"{', '.join(bad)}: no such cross-check; the checks are "
                                   f"{', '.join(known)} (docs/crosschecks.md)"])
    return frozenset(ids)


def gate(findings: Sequence[Finding], accept: frozenset[str], source: str) -> GateResult:
    """Refuse (:class:`CrossCheckRefusal`) when an error is not accepted by id; else what was accepted."""
    errors = [f for f in findings if f.severity is Severity.ERROR]
    blocking = [f for f in errors if f.check_id not in accept]
    if blocking:
        raise CrossCheckRefusal(source, blocking)
    return GateResult(tuple(findings), tuple(errors), tuple(f for f in findings if f.severity is Severity.WARNING))
