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
from sims.scenario import camera_statement, estimator_note

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
        "estimator_note": estimator_note(sc.estimator)
        + ("; angle of attack from a vane read as truth" if sc.vehicle in FIXED_WING_VEHICLES else ""),
        # the periods flown (not given: the 100 Hz default, sims.scenario.default_period), in seconds
        "periods": {"tick_s": sc.dt_s, "core_s": sc.core_every * sc.dt_s, "nav_s": sc.nav_every * sc.dt_s},
        "terrain": sc.ground,
        "camera": camera_statement(sc),
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
          "m0": "1 (0..1)", "m1": "1 (0..1)", "m2": "1 (0..1)", "m3": "1 (0..1)",
          # the sensor voter's column, in every EKF run's log since the EKF is the default
          "imu_lanes_ok": "count (IMU lanes not isolated)", "imu_nav_health": "1 (0..1)",
          "imu_fdi_state": "code (merlin.redundancy FDI state)", "ap_lane": "index (autopilot lane flown)",
          "ap_lanes_live": "count (autopilot lanes alive)", "mag_lanes_ok": "count (lanes not isolated)",
          "baro_lanes_ok": "count (lanes not isolated)", "gps_lanes_ok": "count (lanes not isolated)"}


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
    write_flight_ulog(p, {**r.log, **r.aux}, r.events, meta, r.gps_fixes)
    return p


def _fence_geometry(r: RunResult) -> tuple[Any, Any]:
    """(allowed area, keep-out area) as shapely geometries in (north, east) metres; None where absent."""
    fence = build_core_config(r.config).fence
    if fence is None:
        return None, None
    return fence.allowed_area, fence.exclusion_area


def _draw_fence(ax: Any, allowed: Any, excl: Any, lw: float = 1.5, labels: bool = True) -> None:
    def draw(geom: Any, **kw: Any) -> None:
        if geom is None or geom.is_empty:
            return
        label = kw.pop("label", None)
        for g in getattr(geom, "geoms", [geom]):
            if g.geom_type != "Polygon":
                continue
            n, e = g.exterior.xy  # coordinates are (north, east)
            ax.plot(e, n, label=label, **kw)
            label = None
            for hole in g.interiors:
                hn, he = hole.xy
                ax.plot(he, hn, **kw)

    draw(allowed, color="tab:green", lw=lw, label="inclusion" if labels else None)
    draw(excl, color="tab:red", lw=lw, label="keep-out" if labels else None)


def _nearest_edges(allowed: Any, excl: Any, track_ne: np.ndarray) -> list[tuple[float, Any, Any]]:
    """(distance, point on the track, point on the edge) to the nearest inclusion edge and the nearest
    keep-out edge, in (north, east) metres, nearest first."""
    from shapely.geometry import LineString, MultiPoint
    from shapely.ops import nearest_points

    pts = track_ne[np.isfinite(track_ne).all(axis=1)]
    if len(pts) == 0:
        return []
    path = LineString(pts) if len(pts) > 1 and np.ptp(pts, axis=0).any() else MultiPoint(pts)
    out = []
    for edges in _edge_lines(allowed, excl):
        a, b = nearest_points(path, edges)
        out.append((a.distance(b), a, b))
    return sorted(out, key=lambda x: x[0])


def _edge_lines(allowed: Any, excl: Any) -> list[Any]:
    """The inclusion edges and the keep-out edges (the allowed area's boundary also runs round the
    keep-out zones cut out of it: those parts are keep-out edges, not inclusion ones)."""
    out = []
    keep_out = excl.boundary if excl is not None and not excl.is_empty else None
    if allowed is not None and not allowed.is_empty:
        inclusion = allowed.boundary
        if keep_out is not None:
            inclusion = inclusion.difference(keep_out.buffer(0.01))
        if not inclusion.is_empty:
            out.append(inclusion)
    if keep_out is not None:
        out.append(keep_out)
    return out


def _edge_kinds(allowed: Any, excl: Any, edges: list[tuple[float, Any, Any]]) -> list[str]:
    """"inclusion" or "keep-out" for each of ``_nearest_edges``' entries (the boundary it lies on)."""
    out = []
    for _, _, b in edges:
        da = allowed.boundary.distance(b) if allowed is not None and not allowed.is_empty else np.inf
        de = excl.boundary.distance(b) if excl is not None and not excl.is_empty else np.inf
        out.append("keep-out" if de <= da else "inclusion")  # (a keep-out edge is on both boundaries)
    return out


def ground_track_view(track_ne: np.ndarray, edges: list[tuple[float, Any, Any]]) -> tuple[float, float, float, float]:
    """(east min, east max, north min, north max) of the main view: the flight, padded by 15 % of its extent
    (at least 10 m), widened to show its nearest fence edges when they are within three flight extents
    (a 20 m hover beside a 2 km range is framed on the hover and the edge it came closest to)."""
    pts = track_ne[np.isfinite(track_ne).all(axis=1)]
    if len(pts) == 0:
        pts = np.zeros((1, 2))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    extent = float(max(np.max(hi - lo), 20.0))
    for d, _, edge in edges:
        if d <= 3.0 * extent:
            lo = np.minimum(lo, [edge.x, edge.y])
            hi = np.maximum(hi, [edge.x, edge.y])
    pad = max(10.0, 0.15 * float(np.max(hi - lo)))
    lo, hi = lo - pad, hi + pad
    # no narrower than 2:1 either way, so a straight-line flight still reads as a map
    span = hi - lo
    need = np.maximum(span, 0.5 * float(np.max(span)))
    mid = (lo + hi) / 2
    lo, hi = mid - need / 2, mid + need / 2
    return float(lo[1]), float(hi[1]), float(lo[0]), float(hi[0])


def plot_ground_track(r: RunResult, out: Path) -> Path:
    """The flight framed on itself and its nearest fence edges (the distance to each drawn), the whole
    range as an inset with the main view's box."""
    L = r.log
    fig, ax = plt.subplots(figsize=(7, 7))
    allowed, excl = _fence_geometry(r)
    _draw_fence(ax, allowed, excl)
    track = np.stack([L["truth_n"], L["truth_e"]], axis=1)
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
    edges = _nearest_edges(allowed, excl, track)
    e0, e1, n0, n1 = ground_track_view(track, edges)
    notes = []
    for (d, a_pt, b_pt), kind in zip(edges, _edge_kinds(allowed, excl, edges), strict=True):
        shown = e0 <= b_pt.y <= e1 and n0 <= b_pt.x <= n1
        if shown:
            ax.plot([a_pt.y, b_pt.y], [a_pt.x, b_pt.x], color="0.3", lw=0.8, ls="--")
            ax.annotate(f"{d:.1f} m", ((a_pt.y + b_pt.y) / 2, (a_pt.x + b_pt.x) / 2), fontsize=8, color="0.2")
        notes.append(f"nearest {kind} edge: {d:.1f} m" + ("" if shown else " (outside this view)"))
    if notes:
        ax.text(0.01, 0.99, "\n".join(notes), transform=ax.transAxes, va="top", fontsize=8,
                bbox={"facecolor": "white", "alpha": 0.8, "lw": 0})
    ax.set_xlim(e0, e1)
    ax.set_ylim(n0, n1)
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="box")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)
    ax.set_title(f"{r.scenario.name}: ground track (truth) and the nearest fence edges")
    if allowed is not None and not allowed.is_empty:
        inset = ax.inset_axes((1.03, 0.62, 0.38, 0.38))  # beside the plot: it never hides the flight
        _draw_fence(inset, allowed, excl, lw=0.8, labels=False)
        inset.plot(L["truth_e"], L["truth_n"], color="tab:blue", lw=0.8)
        inset.plot([e0, e1, e1, e0, e0], [n0, n0, n1, n1, n0], color="k", lw=0.8)
        inset.set_aspect("equal", adjustable="datalim")
        inset.set_xticks([])
        inset.set_yticks([])
        inset.set_xlabel("whole range", fontsize=7)
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
