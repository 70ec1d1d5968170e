"""Figures for the review and the campaign report, as PNG bytes (embedded base64 in the HTML report)."""

from __future__ import annotations

import io
import math
from typing import Any

import matplotlib.pyplot as plt
import numpy as np

from merlin.campaign.limits import HEADINGS_DEG, fence_of, speeds_mps, trigger_grid
from merlin.config.models import MerlinConfig

METRIC_LABELS = {
    "takeover_latency_s": "takeover latency: fault onset to revocation [s]",
    "min_fence_margin_m": "minimum fence margin [m]",
    "max_fence_breach_m": "maximum fence breach [m]",
    "nav_error_max_m": "maximum horizontal navigation error [m]",
}


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _draw(ax: Any, geom: Any, **kw: Any) -> None:
    if geom is None or geom.is_empty:
        return
    for g in getattr(geom, "geoms", [geom]):
        if g.geom_type != "Polygon":
            continue
        n, e = g.exterior.xy  # x = north, y = east
        ax.plot(e, n, **kw)
        kw.pop("label", None)
        for hole in g.interiors:
            hn, he = hole.xy
            ax.plot(he, hn, **kw)


def fence_map(cfg: MerlinConfig) -> bytes:
    fence = fence_of(cfg)
    fig, ax = plt.subplots(figsize=(5.5, 5.5))
    if fence is not None:
        _draw(ax, fence.allowed_area, color="tab:green", lw=1.5, label="allowed (inclusion minus keep-out)")
        _draw(ax, fence.exclusion_area, color="tab:red", lw=1.5, label="keep-out")
        if fence.allowed_area is not None and cfg.geofence.margin_m > 0:
            inner = fence.allowed_area.buffer(-cfg.geofence.margin_m)
            _draw(ax, inner, color="tab:green", lw=0.8, ls="--", label=f"margin {cfg.geofence.margin_m:g} m")
    ax.plot([0], [0], marker="^", color="k", ms=8, ls="", label="home")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    ax.set_title(f"{cfg.name}: fence (local frame about home)", fontsize=9)
    return _png(fig)


def trigger_curves(cfg: MerlinConfig) -> bytes:
    """Trigger distance against speed for several headings, and against heading for several speeds."""
    speeds = speeds_mps(cfg)
    grid = trigger_grid(cfg, speeds)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    for i, h in enumerate(HEADINGS_DEG):
        a1.plot(speeds, grid[i], label=f"heading {h:g} deg")
    a1.axvline(cfg.vehicle.max_speed_h_mps, color="k", ls=":", lw=0.8, label="vehicle max speed")
    a1.set_xlabel("horizontal speed [m/s]")
    a1.set_ylabel("trigger distance from the boundary [m]")
    a1.grid(alpha=0.3)
    a1.legend(fontsize=7)
    headings = np.linspace(0.0, 180.0, 73)
    vmax = cfg.vehicle.max_speed_h_mps
    for v in sorted({round(vmax * f, 1) for f in (0.25, 0.5, 0.75, 1.0)}):
        g = trigger_grid(cfg, np.array([v]), tuple(float(h) for h in headings))[:, 0]
        a2.plot(headings, g, label=f"{v:g} m/s")
    a2.set_xlabel("heading from the boundary's outward normal [deg] (0: head-on, 90: parallel)")
    a2.set_ylabel("trigger distance [m]")
    a2.grid(alpha=0.3)
    a2.legend(fontsize=7)
    fig.suptitle(f"{cfg.name}: where the fence takes control ({cfg.geofence.mode.value}, "
                 f"{cfg.vehicle.type.value}, sigma_h = 0)", fontsize=10)
    return _png(fig)


def histograms(records: list[dict[str, Any]]) -> bytes:
    fig, axes = plt.subplots(2, 2, figsize=(11, 6.5))
    ok = [r for r in records if r.get("status") == "ok"]
    for ax, (key, label) in zip(axes.ravel(), METRIC_LABELS.items(), strict=True):
        vals = [(r.get("metrics") or {}).get(key) for r in ok]
        v = np.array([x for x in vals if x is not None and math.isfinite(x)], dtype=float)
        if len(v):
            ax.hist(v, bins=min(40, max(5, len(v) // 5)), color="tab:blue", alpha=0.8)
            ax.axvline(float(np.median(v)), color="k", lw=0.8, ls="--", label=f"median {np.median(v):.3g}")
            ax.legend(fontsize=7)
        else:
            ax.text(0.5, 0.5, "no values", ha="center", va="center", transform=ax.transAxes)
        ax.set_title(f"{label} (n={len(v)})", fontsize=9)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return _png(fig)


def pass_rates(agg: dict[str, Any]) -> bytes:
    ex = agg["expectations"]
    fig, ax = plt.subplots(figsize=(10, 0.3 * max(4, len(ex)) + 1))
    if ex:
        y = np.arange(len(ex))
        rate = np.array([e["pass_rate"] for e in ex])
        lo = rate - np.array([e["wilson95"][0] for e in ex])
        hi = np.array([e["wilson95"][1] for e in ex]) - rate
        colors = ["tab:green" if e["passed"] == e["n"] else "tab:red" for e in ex]
        ax.barh(y, rate, color=colors, alpha=0.6)
        ax.errorbar(rate, y, xerr=[lo, hi], fmt="none", ecolor="k", capsize=3, lw=1)
        ax.set_yticks(y, [f"{e['scenario']}: {e['name']}"[:70] for e in ex], fontsize=7)
        ax.invert_yaxis()
    ax.set_xlim(0, 1.02)
    ax.set_xlabel("pass rate with Wilson 95 % interval")
    ax.grid(alpha=0.3, axis="x")
    return _png(fig)


def close_all() -> None:
    """Close every figure (after one failed half-drawn)."""
    plt.close("all")


def varied_keys(records: list[dict[str, Any]]) -> list[str]:
    """The numeric keys the runs that flew varied, sorted."""
    return sorted({k for r in records if r.get("status") == "ok" for k, v in (r.get("samples") or {}).items()
                   if isinstance(v, int | float) and not isinstance(v, bool)})


def samples_vs_margin(records: list[dict[str, Any]]) -> bytes | None:
    """Each varied numeric key against the run's minimum fence margin (failures in red)."""
    ok = [r for r in records if r.get("status") == "ok"]
    keys = varied_keys(records)
    if not keys:
        return None
    keys = keys[:6]
    fig, axes = plt.subplots(1, len(keys), figsize=(3.6 * len(keys), 3.2), squeeze=False)
    for ax, k in zip(axes[0], keys, strict=True):
        pts = [(r["samples"][k], r["metrics"].get("min_fence_margin_m"), r.get("passed")) for r in ok
               if k in (r.get("samples") or {}) and r["metrics"].get("min_fence_margin_m") is not None]
        for passed, c in ((True, "tab:blue"), (False, "tab:red")):
            xs = [p[0] for p in pts if bool(p[2]) == passed]
            ys = [p[1] for p in pts if bool(p[2]) == passed]
            if xs:
                ax.scatter(xs, ys, s=8, color=c, label="passed" if passed else "failed")
        ax.set_xlabel(k, fontsize=8)
        ax.set_ylabel("min fence margin [m]", fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return _png(fig)
