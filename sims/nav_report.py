"""The navigation page of a run report (``nav.png``), for runs with the fusion EKF.

Four panels ("position error against distance for GPS, VO+INS and INS-only;
innovation test ratios with the spoof onset and detection marked"):

1. horizontal estimate error against the distance flown, coloured by the navigation mode the filter was
   in (GPS, VO, INERTIAL, LOST), with the published 2σ;
2. the GPS tests as ratios to their limits (position and velocity NIS against their gates, the innovation,
   window and GPS-VO CUSUMs against their threshold): above 1 is a rejection or an exclusion. GPS fault
   onsets are drawn in red, exclusions in black, first single-epoch rejections dotted;
3. the VO frames: accepted and fused, or refused by the pipeline's own quality;
4. the navigation mode and Merlin's behaviour against time.

Called from ``sims.report.write_all``; reads only the ``RunResult`` (its log, events and ``nav`` trace).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np

from merlin.core.types import Behavior, NavMode

MODE_COLORS = {NavMode.GPS: "tab:green", NavMode.VO: "tab:blue", NavMode.INERTIAL: "tab:orange",
               NavMode.LOST: "tab:red"}


def distance_flown_m(log: dict[str, np.ndarray]) -> np.ndarray:
    """Cumulative horizontal path length of the truth, m."""
    dn = np.diff(log["truth_n"], prepend=log["truth_n"][:1])
    de = np.diff(log["truth_e"], prepend=log["truth_e"][:1])
    return np.cumsum(np.hypot(dn, de))


def _mark_events(ax: Any, events: list[dict[str, Any]]) -> None:
    for e in events:
        if e["type"] == "fault_start" and str(e.get("fault", "")).startswith("gps"):
            ax.axvline(e["t"], color="tab:red", lw=1.0)
        elif e["type"] == "nav_excluded":
            ax.axvline(e["t"], color="k", lw=1.0, ls="--")
    rej = [e["t"] for e in events if e["type"] == "nav_rejected" and str(e.get("source", "")).startswith("gps")]
    if rej:
        ax.axvline(rej[0], color="tab:purple", lw=0.8, ls=":")


def plot_nav(r: Any, out: Path) -> Path | None:
    """Write ``nav.png`` for a run with ``estimator: ekf``; None for other runs."""
    if r.scenario.estimator != "ekf" or not r.nav:
        return None
    L, nav, events = r.log, r.nav, r.events
    t = L["t"]
    err = np.hypot(L["est_n"] - L["truth_n"], L["est_e"] - L["truth_e"])
    dist = distance_flown_m(L)
    mode = L["nav_mode"].astype(int)
    fig, axes = plt.subplots(4, 1, figsize=(11, 12), gridspec_kw={"height_ratios": [3, 3, 1.6, 1.6]})
    a1, a2, a3, a4 = axes

    for m, c in MODE_COLORS.items():
        sel = mode == int(m)
        if sel.any():
            a1.scatter(dist[sel], err[sel], s=3, color=c, label=f"{m.name} error")
    a1.plot(dist, 2.0 * L["sigma_h"], color="k", lw=0.8, ls="--", label="published 2σ")
    a1.set_xlabel("distance flown [m]")
    a1.set_ylabel("horizontal error [m]")
    a1.set_yscale("symlog", linthresh=1.0)
    a1.grid(alpha=0.3)
    a1.legend(fontsize=8, loc="upper left")
    a1.set_title(f"{r.scenario.name}: estimate error against distance flown, by navigation mode")

    g, gates = nav.get("gps", {}), nav.get("gates", {})
    if g and len(g.get("t", ())):
        gt = g["t"]
        a2.plot(gt, g["nis_pos"] / gates["gps_pos"], lw=0.8, label="NIS pos / gate")
        a2.plot(gt, g["nis_vel"] / gates["gps_vel"], lw=0.8, label="NIS vel / gate")
        for key, label in (("cusum", "innovation CUSUM"), ("window_cusum", "window CUSUM"),
                           ("vo_cusum", "GPS-VO CUSUM")):
            if key in g:
                a2.plot(gt, g[key] / gates["cusum"], lw=1.2, label=f"{label} / limit")
        a2.axhline(1.0, color="tab:red", lw=0.8)
        a2.set_yscale("symlog", linthresh=1.0)
    _mark_events(a2, events)
    a2.set_ylabel("test ratio")
    a2.set_xlim(t[0], t[-1])
    a2.grid(alpha=0.3)
    a2.legend(fontsize=7, loc="upper left", ncol=3)
    a2.set_title("GPS tests (red line: GPS fault onset; black dashed: GPS excluded; dotted: first rejection)")

    vo = nav.get("vo", {})
    if vo and len(vo.get("t", ())):
        vt = vo["t"]
        fused = vo["fused"] > 0.5
        valid = vo["valid"] > 0.5
        a3.scatter(vt[fused], np.full(fused.sum(), 2.0), s=2, color="tab:blue", label="fused")
        a3.scatter(vt[valid & ~fused], np.full((valid & ~fused).sum(), 1.0), s=4, color="tab:orange",
                   label="valid, rejected by the filter")
        a3.scatter(vt[~valid], np.zeros((~valid).sum()), s=2, color="tab:red", label="refused by the pipeline")
        cost = nav.get("cpu_vo_ms_per_frame")
        if cost is not None:
            a3.text(0.99, 0.9, f"{nav['frames']} frames; VO {cost:.1f} ms, render "
                    f"{nav['cpu_render_ms_per_frame']:.1f} ms CPU per frame", transform=a3.transAxes,
                    ha="right", va="top", fontsize=7)
        a3.legend(fontsize=7, loc="lower left", ncol=3)
    else:
        a3.text(0.5, 0.5, "no camera in this run", transform=a3.transAxes, ha="center")
    a3.set_yticks([0, 1, 2], ["refused", "rejected", "fused"])
    a3.set_xlim(t[0], t[-1])
    a3.set_ylim(-0.5, 2.5)
    a3.grid(alpha=0.3)
    a3.set_title("visual odometry frames")

    a4.step(t, mode, where="post", color="tab:blue", label="nav mode")
    a4.set_yticks([m.value for m in NavMode], [m.name for m in NavMode])
    a4b = a4.twinx()
    a4b.step(t, L["behavior"], where="post", color="tab:gray", lw=0.8)
    a4b.set_yticks([b.value for b in Behavior], [b.name for b in Behavior], fontsize=6)
    _mark_events(a4, events)
    a4.set_xlim(t[0], t[-1])
    a4.set_xlabel("t [s]")
    a4.grid(alpha=0.3)
    a4.set_title("navigation mode (blue, left) and Merlin's behaviour (grey, right)")
    fig.tight_layout()
    p = out / "nav.png"
    fig.savefig(p, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return p
