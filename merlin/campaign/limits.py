"""What a configuration's limits mean before flying: fence trigger distances, and the cross-checks' findings.

Pure: a validated :class:`MerlinConfig` in, tables and findings out. Shared by ``merlin review`` and the
campaign report, so both say the same thing about the same file (the findings come from the one registry
of cross-checks, :mod:`merlin.config.crosschecks`). Trigger distances come from
:func:`merlin.core.geofence.trigger_distance_m`, the closed form the core's check agrees with.
"""

from __future__ import annotations

import math

import numpy as np

from merlin.config.crosschecks import Finding, run_checks
from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.config.summary import Table
from merlin.core.geofence import Fence, FenceParams, trigger_distance_m

#: headings relative to the boundary's outward normal shown in tables and plots (0: head-on)
HEADINGS_DEG = (0.0, 30.0, 45.0, 60.0, 90.0)


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


def findings(cfg: MerlinConfig) -> list[Finding]:
    """The configuration's cross-checks (:mod:`merlin.config.crosschecks`, without a vehicle model), so the
    campaign report says what ``merlin review`` says about the same file."""
    return run_checks(cfg)
