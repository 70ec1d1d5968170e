"""What a run leaves behind for a reviewer: ``summary.json`` (a stable contract), the columnar log
(Parquet) and plots (ground track with the fence, authority timeline, envelope parameters against their
limits with the exceedances shaded, as the Merlin paper's Figure 5)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from merlin import _build
from merlin.config.runtime import build_core_config, envelope_limits
from merlin.core.types import Authority, Behavior, CommandKind, NavMode
from sims.expectations import Verdict
from sims.runner import FIXED_WING_VEHICLES, RunResult

SUMMARY_VERSION = 1


def _clean(x: Any) -> Any:
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    return x


def summary_dict(r: RunResult, verdicts: list[Verdict]) -> dict[str, Any]:
    sc = r.scenario
    return _clean({
        "summary_version": SUMMARY_VERSION,
        "scenario": sc.name,
        "description": sc.description,
        "seed": sc.seed,
        "duration_s": sc.duration_s,
        "estimator": sc.estimator,
        "estimator_note": ("truth plus modelled navigation errors (a stand-in for the EKF)"
                           if sc.estimator == "truth_plus_noise" else "fusion EKF on the simulated sensors")
        + ("; angle of attack from a vane read as truth" if sc.vehicle in FIXED_WING_VEHICLES else ""),
        "passed": all(v.passed for v in verdicts),
        "config_name": r.config.name,
        "config_sha256": r.config_sha256,
        "expectations": [v.to_dict() for v in verdicts],
        "events": r.events,
        "metrics": {k: v for k, v in r.metrics.items() if k != "wall_time_s"},
        # wall-clock figures: the only fields that differ between two runs of the same scenario and seed
        # (and the build that ran: compiled or pure Python, merlin._build)
        "timing": {"wall_time_s": r.metrics["wall_time_s"], "realtime_factor": r.metrics["realtime_factor"],
                   "build": _build.describe()},
        "log_digest_sha256": r.decisions_digest,
        "fence_triggers": [{"t": t, "north_m": n, "east_m": e} for t, n, e in r.fence_triggers],
        "controller_log": r.controller_log,
    })


def write_summary(r: RunResult, verdicts: list[Verdict], out: Path) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    p = out / "summary.json"
    d = summary_dict(r, verdicts)
    p.write_text(json.dumps(d, indent=2, sort_keys=False) + "\n")
    return p


#: The log's angle columns, in radians in the run (SI inside), written in degrees under a ``_deg`` name so
#: that the Parquet file has one unit per quantity: the envelope's columns are in the configuration's
#: degrees (``env_roll_deg``)
_ANGLES_RAD = ("truth_roll", "truth_pitch", "truth_yaw", "cmd_roll", "cmd_pitch", "sp_roll")
#: Coded columns: their values' names (the enums of merlin.core.types)
_ENUMS = {"authority": Authority, "behavior": Behavior, "nav_mode": NavMode, "cmd_kind": CommandKind}
_BOOLS = ("armed", "landed")
_UNITS = {"t": "s", "sigma_h": "m", "battery_frac": "1 (0..1)", "wind_n": "m/s", "wind_e": "m/s",
          "fence_margin": "m (signed: negative outside)", "cmd_thrust": "1 (0..1)", "cmd_blend": "1 (0..1)",
          "m0": "1 (0..1)", "m1": "1 (0..1)", "m2": "1 (0..1)", "m3": "1 (0..1)"}


def _unit(name: str) -> str:
    """A log column's unit, from its name (merlin.ulog.topics.unit_of for the suffixed ones)."""
    from merlin.ulog.topics import unit_of

    if name in _UNITS:
        return _UNITS[name]
    if name.endswith(("_vn", "_ve", "_vd")):
        return "m/s"
    if name.split("_")[0] in ("truth", "est") and name.endswith(("_n", "_e", "_d")):
        return "m"
    return unit_of(name.removeprefix("env_"))


def log_table(r: RunResult) -> pa.Table:
    """The run's log as a self-describing table: each field's unit (``unit``) and, for coded columns, the
    names of the codes (``labels``, JSON) in its metadata, and a dictionary-encoded ``<column>_name`` beside
    it; booleans as booleans; angles in degrees (``_deg``); the latitude, longitude and altitude (WGS84,
    metres AMSL) of the truth and of the estimate beside their north/east/down. The log's values themselves
    (and so the run's decisions_digest, a hash of the log) are unchanged."""
    from merlin.geodesy import LocalFrame

    h = r.config.home
    frame = LocalFrame(h.lat_deg, h.lon_deg, h.alt_amsl_m)
    fields: list[pa.Field] = []
    arrays: list[pa.Array] = []

    def add(name: str, values: Any, unit: str = "", labels: dict[int, str] | None = None) -> None:
        meta = {}
        if unit:
            meta[b"unit"] = unit.encode()
        if labels is not None:
            meta[b"labels"] = json.dumps({str(k): v for k, v in labels.items()}).encode()
        arr = pa.array(values)
        arrays.append(arr)
        fields.append(pa.field(name, arr.type, metadata=meta or None))

    L = r.log
    for name, col in L.items():
        if name in _ANGLES_RAD:
            add(f"{name}_deg", np.degrees(col), "deg")
        elif name in _ENUMS:
            enum = _ENUMS[name]
            labels = {int(m): m.name for m in enum}
            add(name, col.astype(np.uint8), "", labels)
            # the dictionary is indexed by the code itself (the enums number their members from 0)
            words = [labels.get(i, str(i)) for i in range(max(labels) + 1)]
            names = pa.DictionaryArray.from_arrays(pa.array(col.astype(np.int8)), pa.array(words))
            arrays.append(names)
            fields.append(pa.field(f"{name}_name", names.type))
        elif name in _BOOLS or name.startswith("mon_"):
            add(name, col > 0.5)
        else:
            add(name, col, _unit(name))
        if name == "truth_d":
            lat, lon, alt = frame.geodetic_from_ned(np.stack([L["truth_n"], L["truth_e"], L["truth_d"]], axis=1))
            add("truth_lat_deg", lat, "deg (WGS84)")
            add("truth_lon_deg", lon, "deg (WGS84)")
            add("truth_alt_m", alt, "m AMSL")
        elif name == "est_d":
            lat, lon, alt = frame.geodetic_from_ned(np.stack([L["est_n"], L["est_e"], L["est_d"]], axis=1))
            add("est_lat_deg", lat, "deg (WGS84)")
            add("est_lon_deg", lon, "deg (WGS84)")
            add("est_alt_m", alt, "m AMSL")
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields))


def write_log(r: RunResult, out: Path) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    table = log_table(r)
    h = r.config.home
    meta = {b"scenario": r.scenario.name.encode(), b"config_sha256": r.config_sha256.encode(),
            b"seed": str(r.scenario.seed).encode(), b"decisions_digest": r.decisions_digest.encode(),
            b"frame": (f"NED metres about home ({h.lat_deg}, {h.lon_deg}, {h.alt_amsl_m} m AMSL), Merlin's "
                       "azimuthal equidistant projection on the WGS84 ellipsoid; body FRD").encode()}
    table = table.replace_schema_metadata(meta)
    p = out / "log.parquet"
    pq.write_table(table, p)
    return p


def write_ulog(r: RunResult, out: Path) -> Path:
    """``flight.ulg``: the run as PX4's topics and Merlin's own (merlin.ulog.flight), for Flight Review,
    PlotJuggler and pyulog; ``merlin replay`` reads it back (docs/field-tools.md)."""
    from merlin.ulog.flight import flight_meta, write_flight_ulog

    out.mkdir(parents=True, exist_ok=True)
    sc = r.scenario
    meta = flight_meta(r.config, sc.vehicle in FIXED_WING_VEHICLES, {
        "merlin_scenario": sc.name, "merlin_seed": int(sc.seed), "merlin_config_sha256": r.config_sha256,
        "merlin_estimator": sc.estimator, "merlin_decisions_digest": r.decisions_digest}, "MERLIN_SITL")
    p = out / "flight.ulg"
    write_flight_ulog(p, {**r.log, **r.aux}, r.events, meta)
    return p


def _fence_patches(ax: Any, r: RunResult) -> None:
    cfg = build_core_config(r.config)
    fence = cfg.fence
    if fence is None:
        return
    allowed = fence.allowed_area
    excl = fence.exclusion_area

    def draw(geom: Any, **kw: Any) -> None:
        if geom is None or geom.is_empty:
            return
        geoms = getattr(geom, "geoms", [geom])
        for g in geoms:
            if g.geom_type != "Polygon":
                continue
            n, e = g.exterior.xy  # coordinates are (north, east)
            ax.plot(e, n, **kw)
            for hole in g.interiors:
                hn, he = hole.xy
                ax.plot(he, hn, **kw)

    draw(allowed, color="tab:green", lw=1.5, label="inclusion")
    draw(excl, color="tab:red", lw=1.5, label="keep-out")


def plot_ground_track(r: RunResult, out: Path) -> Path:
    L = r.log
    fig, ax = plt.subplots(figsize=(7, 7))
    _fence_patches(ax, r)
    auth = L["authority"]
    colors = {0: "tab:blue", 1: "tab:orange", 2: "tab:purple", 3: "tab:cyan"}
    for a, c in colors.items():
        m = auth == a
        if m.any():
            ax.scatter(L["truth_e"][m], L["truth_n"][m], s=2, color=c)
            ax.plot([], [], marker="o", ls="none", color=c, label=Authority(a).name.lower())
    if r.fence_triggers:
        tn = [x[1] for x in r.fence_triggers]
        te = [x[2] for x in r.fence_triggers]
        ax.scatter(te, tn, marker="x", s=80, color="k", zorder=5, label="fence triggered")
    ax.plot([0], [0], marker="^", color="k", ms=6, ls="none", label="home")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"{r.scenario.name}: ground track (truth)")
    p = out / "ground_track.png"
    fig.savefig(p, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return p


def plot_authority(r: RunResult, out: Path) -> Path:
    L = r.log
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 4.5), sharex=True)
    a1.step(L["t"], L["authority"], where="post", color="tab:purple")
    a1.set_yticks([a.value for a in Authority], [a.name for a in Authority])
    a1.set_ylabel("authority")
    a1.grid(alpha=0.3)
    a2.step(L["t"], L["behavior"], where="post", color="tab:blue")
    a2.set_yticks([b.value for b in Behavior], [b.name for b in Behavior], fontsize=7)
    a2.set_ylabel("trusted behaviour")
    a2.set_xlabel("t [s]")
    a2.grid(alpha=0.3)
    for e in r.events:
        if e["type"] == "revoked":
            for ax in (a1, a2):
                ax.axvline(e["t"], color="tab:red", lw=0.8, ls="--")
            a1.annotate(e.get("reason", ""), (e["t"], 2.6), fontsize=7, color="tab:red", rotation=90, va="top")
        elif e["type"] == "granted":
            a1.axvline(e["t"], color="tab:green", lw=0.8, ls=":")
    a1.set_title(f"{r.scenario.name}: authority timeline (red: revocation, green: grant)")
    p = out / "authority.png"
    fig.savefig(p, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return p


def plot_envelope(r: RunResult, out: Path) -> Path:
    L = r.log
    limits = envelope_limits(r.config)
    n = len(limits)
    cols = 3
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(13, 2.3 * rows), sharex=True)
    axes = np.atleast_1d(axes).ravel()
    t = L["t"]
    for ax, lim in zip(axes, limits, strict=False):
        y = L[f"env_{lim.name}"]
        lo, hi = lim.shown_limit(-math.inf), lim.shown_limit(math.inf)
        ax.plot(t, y, lw=0.8, color="tab:blue")
        ax.axhline(lo, color="tab:red", lw=0.8, ls="--")
        ax.axhline(hi, color="tab:red", lw=0.8, ls="--")
        out_of = (y < lo) | (y > hi)
        ax.fill_between(t, 0, 1, where=out_of, color="tab:red", alpha=0.2, transform=ax.get_xaxis_transform())
        ax.set_title(f"{lim.name} (duration {lim.duration_s:g} s)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        span = max(abs(lo), abs(hi))
        ymin, ymax = float(np.nanmin(y)) if len(y) else lo, float(np.nanmax(y)) if len(y) else hi
        ax.set_ylim(min(lo - 0.1 * span, ymin), max(hi + 0.1 * span, ymax))
        for e in r.events:
            if e["type"] == "revoked" and e.get("reason_detail", {}).get("parameter") == lim.name:
                ax.axvline(e["t"], color="k", lw=1.0)
    for ax in axes[n:]:
        ax.set_visible(False)
    fig.suptitle(f"{r.scenario.name}: envelope parameters against their limits (shaded: outside; black: revocation)",
                 fontsize=10)
    fig.tight_layout()
    p = out / "envelope.png"
    fig.savefig(p, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return p


def write_all(r: RunResult, verdicts: list[Verdict], out: Path, plots: bool = True) -> dict[str, Path]:
    out.mkdir(parents=True, exist_ok=True)
    files = {"summary": write_summary(r, verdicts, out), "log": write_log(r, out), "ulog": write_ulog(r, out)}
    if plots:
        files["ground_track"] = plot_ground_track(r, out)
        files["authority"] = plot_authority(r, out)
        files["envelope"] = plot_envelope(r, out)
        from sims.nav_report import plot_nav  # navigation page, fusion-EKF runs only (docs/navigation.md)

        nav_png = plot_nav(r, out)
        if nav_png is not None:
            files["nav"] = nav_png
        from sims.redundancy_plot import (
            plot_redundancy,  # voted lanes, FDI, selected lane (docs/redundancy.md)
        )

        red_png = plot_redundancy(r, out)
        if red_png is not None:
            files["redundancy"] = red_png
    events_path = out / "events.jsonl"
    with events_path.open("w") as f:
        for e in r.events:
            f.write(json.dumps(_clean(e)) + "\n")
    files["events"] = events_path
    return files
