"""The redundancy plot of a closed-loop run (``redundancy.png``): IMU lanes left in the vote, the duplex
FDI's state and the nav health, the selected autopilot lane and the motor commands, with the voter's,
the FDI's and the lane voter's events marked. Written only when the run's log has redundancy columns
(``merlin/redundancy/lanes.py``)."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt

from sims.runner import RunResult

# event types marked on the plot, with their colour
_MARKED = {
    "imu_isolated": "tab:red",
    "mag_isolated": "tab:red",
    "baro_isolated": "tab:red",
    "gps_isolated": "tab:red",
    "imu_alert": "tab:orange",
    "imu_fault_declared": "tab:red",
    "autopilot_peer_silent": "tab:orange",
    "autopilot_flag_fault": "tab:orange",
    "autopilot_lane_switch": "tab:red",
}


def plot_redundancy(r: RunResult, out: Path) -> Path | None:
    L = r.log
    has_imu, has_lanes = "imu_lanes_ok" in L, "ap_lane" in L
    if not (has_imu or has_lanes):
        return None
    rows = (2 if has_imu else 0) + (2 if has_lanes else 0)
    fig, axes = plt.subplots(rows, 1, figsize=(10, 1.9 * rows + 0.4), sharex=True)
    axes = list(axes) if rows > 1 else [axes]
    t = L["t"]
    i = 0
    if has_imu:
        a = axes[i]
        a.step(t, L["imu_lanes_ok"], where="post", color="tab:blue", label="IMU")
        # with three magnetometers, barometers and GPS receivers (sensor_lanes: 3), theirs too (offset so
        # that equal levels stay visible)
        extra = [(k, c, off) for k, c, off in (("mag_lanes_ok", "tab:orange", -0.06), ("baro_lanes_ok", "tab:green",
                                                                                      -0.12),
                                               ("gps_lanes_ok", "tab:brown", -0.18)) if k in L]
        for k, c, off in extra:
            a.step(t, L[k] + off, where="post", color=c, label=k.split("_")[0])
        if extra:
            a.legend(fontsize=7, loc="lower left", ncol=4)
        a.set_yticks([0, 1, 2, 3], ["0", "1 simplex", "2 duplex", "3 triplex"])
        a.set_ylim(-0.4, 3.4)
        a.set_ylabel("sensor lanes voted" if extra else "IMU lanes voted")
        b = axes[i + 1]
        b.step(t, L["imu_fdi_state"], where="post", color="tab:purple", label="duplex FDI state")
        b.step(t, 3.0 * L["imu_nav_health"], where="post", color="tab:green", ls="--", label="3 x nav health")
        b.set_yticks([0, 1, 2, 3], ["off", "normal", "alert", "fault"])
        b.set_ylabel("PF FDI (seed 003)")
        b.legend(fontsize=7, loc="lower left")
        i += 2
    if has_lanes:
        a = axes[i]
        a.step(t, L["ap_lane"], where="post", color="tab:blue", label="selected lane")
        a.step(t, L["ap_lanes_live"] - 1.0, where="post", color="tab:gray", ls=":", label="lanes alive - 1")
        a.set_yticks([0, 1, 2], ["lane 0", "lane 1", "lane 2"])
        a.set_ylabel("autopilot lane")
        a.legend(fontsize=7, loc="lower left")
        b = axes[i + 1]
        for k in range(4):
            b.plot(t, L[f"m{k}"], lw=0.7, label=f"motor {k}")
        b.set_ylabel("motor command")
        b.legend(fontsize=7, ncol=4, loc="lower left")
        switches = [e["t"] for e in r.events if e["type"] == "autopilot_lane_switch"]
        if switches:  # zoom on the first hand-over: the motors must not jump there
            ts = switches[0]
            m = (t >= ts - 0.15) & (t <= ts + 0.25)
            ins = b.inset_axes((0.62, 0.5, 0.37, 0.48))
            for k in range(4):
                ins.plot(t[m], L[f"m{k}"][m], lw=0.8, marker=".", ms=2)
            ins.axvline(ts, color="tab:red", lw=0.8, ls="--")
            ins.set_title(f"hand-over at {ts:.3f} s", fontsize=7)
            ins.tick_params(labelsize=6)
    for ax in axes:
        ax.grid(alpha=0.3)
        for e in r.events:
            c = _MARKED.get(e["type"])
            if c is not None:
                ax.axvline(e["t"], color=c, lw=0.8, ls="--")
    axes[0].set_title(f"{r.scenario.name}: hardware redundancy (dashed: isolations, alerts, lane switches)")
    axes[-1].set_xlabel("t [s]")
    p = out / "redundancy.png"
    fig.savefig(p, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return p
