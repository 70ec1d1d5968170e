"""What a configuration's limits mean before flying: fence trigger distances and consistency warnings.

Pure: a validated :class:`MerlinConfig` in, tables and findings out. Shared by ``merlin review`` and the
campaign report, so both say the same thing about the same file. Trigger distances come from
:func:`merlin.core.geofence.trigger_distance_m`, the closed form the core's check agrees with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.config.summary import Table
from merlin.core.geofence import Fence, FenceParams, trigger_distance_m

#: headings relative to the boundary's outward normal shown in tables and plots (0: head-on)
HEADINGS_DEG = (0.0, 30.0, 45.0, 60.0, 90.0)


@dataclass(frozen=True, slots=True)
class Finding:
    """One inconsistency: the keys involved and, in numbers, why it matters."""

    keys: tuple[str, ...]
    text: str

    def to_dict(self) -> dict[str, object]:
        return {"keys": list(self.keys), "text": self.text}


def fence_of(cfg: MerlinConfig) -> Fence | None:
    return build_core_config(cfg).fence


def fence_params(cfg: MerlinConfig) -> FenceParams:
    f = fence_of(cfg)
    if f is not None:
        return f.params
    v, g = cfg.vehicle, cfg.geofence
    return FenceParams(mode=g.mode.value, margin_m=g.margin_m, sigma_k=g.sigma_k, vehicle=v.type.value,
                       reaction_time_s=v.reaction_time_s, max_h_decel_mps2=v.max_horizontal_decel_mps2,
                       max_v_decel_mps2=v.max_vertical_decel_mps2, bank_limit_rad=math.radians(v.bank_limit_deg))


def speeds_mps(cfg: MerlinConfig, n: int = 41) -> np.ndarray:
    return np.linspace(0.0, 1.2 * cfg.vehicle.max_speed_h_mps, n)


def trigger_grid(cfg: MerlinConfig, speeds: np.ndarray, headings_deg: tuple[float, ...] = HEADINGS_DEG,
                 sigma_h_m: float = 0.0) -> np.ndarray:
    """``out[i, j]``: trigger distance at ``headings_deg[i]`` and ``speeds[j]``, metres from the boundary."""
    prm = fence_params(cfg)
    return np.array([[trigger_distance_m(prm, float(v), math.radians(h), sigma_h_m) for v in speeds]
                     for h in headings_deg])


def trigger_table(cfg: MerlinConfig, sigma_h_m: float = 0.0) -> Table:
    vmax = cfg.vehicle.max_speed_h_mps
    speeds = np.unique(np.round(np.concatenate([np.arange(0.0, vmax, 2.5), [vmax]]), 3))
    grid = trigger_grid(cfg, speeds, HEADINGS_DEG, sigma_h_m)
    rows = tuple((float(v), *(round(float(grid[i, j]), 2) for i in range(len(HEADINGS_DEG))))
                 for j, v in enumerate(speeds))
    keys = ("speed_mps", *(f"heading_{int(h)}_deg_m" for h in HEADINGS_DEG))
    headers = ("speed (m/s)", *(f"{int(h)} deg (m)" for h in HEADINGS_DEG))
    mode = cfg.geofence.mode.value
    return Table(title=f"Fence trigger distance from the boundary ({mode}, {cfg.vehicle.type.value}, sigma_h "
                 f"{sigma_h_m:g} m; heading from the boundary normal, 0 = head-on)",
                 keys=keys, headers=headers, rows=rows)


def home_to_boundary_m(fence: Fence | None) -> float | None:
    """Horizontal distance from home to the nearest edge of the allowed area (None: no inclusion zone)."""
    if fence is None or fence.allowed_area is None:
        return None
    return float(shapely.distance(shapely.Point(0.0, 0.0), shapely.boundary(fence.allowed_area)))


def findings(cfg: MerlinConfig) -> list[Finding]:
    """Settings that contradict each other, each with the numbers that show it."""
    out: list[Finding] = []
    v, g, w, t = cfg.vehicle, cfg.geofence, cfg.watchdogs, cfg.trusted
    vmax = v.max_speed_h_mps
    env = cfg.envelope.effective()
    stage = cfg.envelope.active_stage
    fence = fence_of(cfg) if g.enabled else None
    if not g.enabled:
        out.append(Finding(("geofence.enabled",), "the geofence is disabled: nothing keeps the vehicle on the range"))
    else:
        for wd in ("controller_heartbeat", "setpoint_stale"):
            timeout = getattr(w, wd).timeout_s
            d = vmax * timeout
            if g.margin_m < d:
                out.append(Finding(
                    ("geofence.margin_m", f"watchdogs.{wd}.timeout_s", "vehicle.max_speed_h_mps"),
                    f"fence margin {g.margin_m:g} m is smaller than the {d:.1f} m covered at the maximum speed "
                    f"{vmax:g} m/s during the {wd} timeout of {timeout:g} s"))
    reach = home_to_boundary_m(fence)
    if reach is not None:
        t_reach = reach / vmax
        for p in ("vel_n_mps", "vel_e_mps", "altitude_m"):
            lim = env[p]
            if lim.enabled and lim.duration_s > t_reach:
                out.append(Finding(
                    (f"envelope.stages.{stage}.{p}.duration_s", "vehicle.max_speed_h_mps"),
                    f"{p} exceedance duration {lim.duration_s:g} s is longer than the {t_reach:.1f} s the vehicle "
                    f"needs at {vmax:g} m/s to reach the fence {reach:.1f} m from home"))
        d0 = trigger_distance_m(fence_params(cfg), vmax, 0.0)
        if d0 >= reach:
            out.append(Finding(
                ("geofence.margin_m", "vehicle.max_speed_h_mps"),
                f"at {vmax:g} m/s head-on the fence trips {d0:.1f} m from the boundary, but home is only "
                f"{reach:.1f} m from it: a flight at full speed is revoked from anywhere"))
    if g.enabled and g.altitude_ceiling_m is not None and t.rtl_altitude_m > g.altitude_ceiling_m:
        out.append(Finding(("trusted.rtl_altitude_m", "geofence.altitude_ceiling_m"),
                           f"RTL climbs to {t.rtl_altitude_m:g} m, above the fence ceiling {g.altitude_ceiling_m:g} m"))
    alt = env["altitude_m"]
    if alt.enabled and t.takeoff_altitude_m < alt.min:
        out.append(Finding((f"envelope.stages.{stage}.altitude_m.min", "trusted.takeoff_altitude_m"),
                           f"take-off altitude {t.takeoff_altitude_m:g} m is below the envelope minimum "
                           f"{alt.min:g} m: a grant right after take-off violates the envelope at once"))
    if alt.enabled and g.enabled and g.altitude_ceiling_m is not None and alt.max > g.altitude_ceiling_m:
        out.append(Finding((f"envelope.stages.{stage}.altitude_m.max", "geofence.altitude_ceiling_m"),
                           f"envelope altitude maximum {alt.max:g} m is above the fence ceiling "
                           f"{g.altitude_ceiling_m:g} m: the fence trips before the envelope limit is reached"))
    o = cfg.operator
    if o.oversight_envelope:
        for p in ("vel_n_mps", "vel_e_mps"):
            lim = env[p]
            if lim.enabled and o.max_speed_h_mps > min(abs(lim.min), abs(lim.max)):
                out.append(Finding((f"envelope.stages.{stage}.{p}", "operator.max_speed_h_mps"),
                                   f"full stick ({o.max_speed_h_mps:g} m/s) exceeds the {p} limits "
                                   f"[{lim.min:g}, {lim.max:g}] that oversee the operator"))
    for p in ("vel_n_mps", "vel_e_mps"):
        lim = env[p]
        if lim.enabled and min(abs(lim.min), abs(lim.max)) > vmax:
            out.append(Finding((f"envelope.stages.{stage}.{p}", "vehicle.max_speed_h_mps"),
                               f"the {p} limits [{lim.min:g}, {lim.max:g}] lie beyond the vehicle's maximum speed "
                               f"{vmax:g} m/s: they can never trip"))
    hb = cfg.handover
    if hb.cooldown_s < w.controller_heartbeat.timeout_s:
        out.append(Finding(("handover.cooldown_s", "watchdogs.controller_heartbeat.timeout_s"),
                           f"cool-down {hb.cooldown_s:g} s is shorter than the heartbeat timeout "
                           f"{w.controller_heartbeat.timeout_s:g} s: a flapping controller can be re-granted at once"))
    return out
