"""Expectations: what a scenario says must be true after the run, checked against its events, log and metrics."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from merlin.core.types import Authority, Behavior, NavMode
from sims.scenario import Expectation


@dataclass(frozen=True, slots=True)
class Verdict:
    name: str
    passed: bool
    detail: str

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "passed": self.passed, "detail": self.detail}


def _at(log: dict[str, np.ndarray], t: float, col: str) -> float:
    ts = log["t"]
    i = int(np.searchsorted(ts, t - 1e-9))
    i = min(max(i, 0), len(ts) - 1)
    return float(log[col][i])


def event_parameter(e: dict[str, Any]) -> str | None:
    """The parameter an event names: an authority event's in its ``reason_detail``, a navigation event's or a
    trusted excursion's at its top level; None when it names none."""
    return e.get("reason_detail", {}).get("parameter", e.get("parameter"))


def _matches(e: dict[str, Any], x: Expectation) -> bool:
    if x.reason is not None and e.get("reason") != x.reason:
        return False
    if x.parameter is not None and event_parameter(e) != x.parameter:
        return False
    if x.lane is not None and e.get("lane") != x.lane:
        return False
    if x.source is not None and e.get("source") != x.source:
        return False
    if e["t"] < x.after_s - 1e-9:
        return False
    if x.duration_s is not None and abs(e.get("reason_detail", {}).get("duration_s", math.nan) - x.duration_s) > 1e-6:
        return False
    return x.not_before_s is None or e["t"] >= x.not_before_s - 1e-9


def _describe(x: Expectation) -> str:
    if x.name:
        return x.name
    parts: list[str] = [x.type]
    for k in ("t", "authority", "behavior", "reason", "parameter", "event", "lane", "source", "after_s", "within_s",
              "m", "mps"):
        v = getattr(x, k)
        if v is not None and not (k == "after_s" and v == 0.0):
            parts.append(f"{k}={v}")
    return " ".join(parts)


def evaluate(x: Expectation, events: list[dict[str, Any]], log: dict[str, np.ndarray],
             metrics: dict[str, float]) -> Verdict:
    name = _describe(x)
    kind = x.type
    if kind == "authority_at":
        assert x.t is not None and x.authority is not None
        got = Authority(int(_at(log, x.t, "authority"))).name
        return Verdict(name, got == x.authority.upper(), f"authority at t={x.t}: {got}")
    if kind == "behavior_at":
        assert x.t is not None and x.behavior is not None
        got = Behavior(int(_at(log, x.t, "behavior"))).name
        return Verdict(name, got == x.behavior.upper(), f"behaviour at t={x.t}: {got}")
    if kind in ("revoked", "granted", "denied", "event"):
        etype = {"revoked": "revoked", "granted": "granted", "denied": "denied"}.get(kind, x.event or "")
        hits = [e for e in events if e["type"] == etype and _matches(e, x)]
        if x.within_s is not None:
            hits = [e for e in hits if e["t"] <= x.after_s + x.within_s + 1e-9]
        ok = len(hits) >= (x.count or 1) if x.count != 0 else not hits
        if hits:
            e = hits[0]
            detail = f"first {etype} at t={e['t']:.4f}"
            rd = e.get("reason_detail")
            if rd:
                detail += f" ({rd['text']})"
        else:
            window = f" in [{x.after_s}, {x.after_s + x.within_s}]" if x.within_s is not None else ""
            detail = f"no matching {etype} event{window}"
        return Verdict(name, ok, detail)
    if kind == "never_revoked":
        hits = [e for e in events if e["type"] == "revoked" and _matches(e, x)]
        return Verdict(name, not hits, "no revocation" if not hits else f"revoked at t={hits[0]['t']:.4f}: "
                       f"{hits[0].get('reason_detail', {}).get('text', '')}")
    if kind == "no_fence_breach":
        b = metrics["max_fence_breach_m"]
        return Verdict(name, b <= 0.0, f"maximum breach {b:.3f} m")
    if kind == "max_fence_breach":
        assert x.m is not None
        b = metrics["max_fence_breach_m"]
        return Verdict(name, b <= x.m, f"maximum breach {b:.3f} m (allowed {x.m} m)")
    if kind == "min_fence_margin":
        assert x.m is not None
        m = metrics["min_fence_margin_m"]
        return Verdict(name, m >= x.m, f"minimum margin {m:.3f} m (required {x.m} m)")
    if kind == "landed_near_home":
        lim = x.m if x.m is not None else 3.0
        d = metrics["final_distance_from_home_m"]
        landed = metrics["final_landed"] > 0.5
        return Verdict(name, landed and d <= lim, f"landed={landed}, {d:.2f} m from home (allowed {lim} m)")
    if kind == "disarmed":
        if x.t is not None:
            return _for_good_by(name, log, "armed", False, x.t, "disarmed")
        armed = bool(log["armed"][-1] > 0.5) if len(log["armed"]) else False
        return Verdict(name, not armed, f"armed at the end: {armed}")
    if kind == "landed_by":
        assert x.t is not None
        return _for_good_by(name, log, "landed", True, x.t, "on the ground (touched down)")
    if kind == "max_command_jump":
        lim = x.mps if x.mps is not None else 0.5
        j = metrics["max_authority_change_command_jump_mps"]
        if math.isnan(j):  # the vehicle does not fly the velocity command itself (the fixed wing)
            return Verdict(name, False, "not applicable: this vehicle's actuator stage does not fly the core's"
                           " velocity command (max_authority_change_command_jump_mps is null)")
        return Verdict(name, j <= lim, f"largest command step at a change of authority {j:.3f} m/s (allowed {lim})")
    if kind == "max_lane_switch_step":
        # hardware redundancy (merlin/redundancy/lanes.py): within SWITCH_WINDOW_S of an autopilot-lane switch, the
        # largest per-tick motor-command step the hand-over adds beyond the incoming lane's own change;
        # default limit: the run's bumpless limit. At least one switch must have happened.
        # Also the raw actuated step near the switch, against the larger of the limit and the largest step
        # the inner loops make elsewhere in the same flight (a hand-over must not stand out of normal
        # control), and the incoming lane must command within one tick of the switch.
        n = metrics.get("lane_switches", 0.0)
        lim = x.step if x.step is not None else metrics.get("bumpless_limit", 0.0)
        s = metrics.get("max_lane_switch_added_step", math.inf)
        raw = metrics.get("max_lane_switch_motor_step", math.inf)
        normal = metrics.get("max_motor_step_outside_switches", math.nan)
        raw_lim = max(lim, normal) if math.isfinite(normal) else lim
        delay = metrics.get("lane_switch_command_delay_ticks", math.inf)
        return Verdict(name, n >= 1 and s <= lim + 1e-12 and raw <= raw_lim + 1e-12 and delay <= 1.0,
                       f"{int(n)} lane switch(es); step added by the hand-over {s:.4f} per tick (allowed {lim:.4f});"
                       f" gap at the switch {metrics.get('lane_switch_handover_gap', math.nan):.4f}; largest "
                       f"step near the switch {raw:.4f} (allowed {raw_lim:.4f}: the limit or the largest"
                       f" elsewhere in flight, {normal:.4f}); incoming lane commanding {delay:g} tick(s) after"
                       f" the switch (allowed 1)")
    if kind == "max_height_loss_after_revocation":
        return _height_loss_after_revocation(name, x, events, log)
    if kind in ("nav_mode_at", "max_nav_error"):
        return _evaluate_nav(x, name, log)
    if kind == "max_tracking_error":
        return _tracking_error(name, x, log)
    return Verdict(name, False, f"unknown expectation type {kind!r}")  # unreachable: the model validates types


def _evaluate_nav(x: Expectation, name: str, log: dict[str, np.ndarray]) -> Verdict:
    """The navigation solution the core saw (``docs/navigation.md``): its mode at a time, or the largest
    horizontal distance between the estimate and the truth over ``[after_s, after_s + within_s]`` (to the
    end without ``within_s``): how far a GPS fault pulled the vehicle, which flies on the estimate."""
    if x.type == "nav_mode_at":
        assert x.t is not None and x.nav_mode is not None
        got = NavMode(int(_at(log, x.t, "nav_mode"))).name
        return Verdict(name, got == x.nav_mode.upper(), f"navigation mode at t={x.t}: {got}")
    assert x.m is not None
    t = log["t"]
    end = x.after_s + x.within_s if x.within_s is not None else math.inf
    sel = (t >= x.after_s - 1e-9) & (t <= end + 1e-9)
    if not sel.any():
        return Verdict(name, False, f"no log rows in [{x.after_s}, {end}]")
    err = np.hypot(log["est_n"][sel] - log["truth_n"][sel], log["est_e"][sel] - log["truth_e"][sel])
    k = int(np.argmax(err))
    return Verdict(name, float(err[k]) <= x.m,
                   f"largest horizontal estimate error {err[k]:.2f} m at t={t[sel][k]:.2f} (allowed {x.m} m)")


def _for_good_by(name: str, log: dict[str, np.ndarray], col: str, want: bool, t: float, what: str) -> Verdict:
    """Whether the boolean log column ``col`` is ``want`` from ``t`` (at the latest) to the end of the run: a
    touchdown or a disarm that happened by ``t`` and was not undone (a bounce back into the air fails).
    The detail gives the start of the final run of ``want``: when it became so for good."""
    ts = log["t"]
    if not len(ts) or ts[-1] < t - 1e-9:
        return Verdict(name, False, f"the run ends before t={t}")
    flags = np.asarray(log[col], dtype=float) > 0.5
    if not want:
        flags = ~flags
    if not flags[-1]:
        return Verdict(name, False, f"not {what} at the end of the run (required by t={t})")
    off = np.flatnonzero(~flags)
    since = float(ts[off[-1] + 1]) if len(off) else float(ts[0])
    return Verdict(name, since <= t + 1e-9, f"{what} for good from t={since:.2f} (required by t={t})")


def _height_loss_after_revocation(name: str, x: Expectation, events: list[dict[str, Any]],
                                  log: dict[str, np.ndarray]) -> Verdict:
    """The true height at the first matching revocation minus the lowest true height after it (to the end of
    the run, or ``within_s`` after the revocation): what taking control back cost in height, e.g. a fixed
    wing's stall recovery. Fails without a matching revocation (nothing was recovered)."""
    if x.m is None:
        return Verdict(name, False, "max_height_loss_after_revocation needs m: the allowed height loss, metres")
    hits = [e for e in events if e["type"] == "revoked" and _matches(e, x)]
    if not hits:
        return Verdict(name, False, "no matching revocation: no recovery to measure")
    t0 = float(hits[0]["t"])
    ts = log["t"]
    k = min(int(np.searchsorted(ts, t0 - 1e-9)), len(ts) - 1)
    end = len(ts) if x.within_s is None else int(np.searchsorted(ts, t0 + x.within_s + 1e-9, side="right"))
    h = -np.asarray(log["truth_d"][k:max(end, k + 1)], dtype=float)
    loss = float(h[0] - h.min())
    return Verdict(name, loss <= x.m, f"height lost after the revocation at t={t0:.3f}: {loss:.2f} m "
                   f"(allowed {x.m} m)")


def _tracking_error(name: str, x: Expectation, log: dict[str, np.ndarray]) -> Verdict:
    """How well a quantity is held after capture, e.g. a fixed wing's height and airspeed on a lap (the seed
    FCU thesis's +-10 m and +-2 m/s after capture, Table 6.1). ``parameter`` is ``height_m`` (the true height
    above home) or an envelope parameter (its ``env_`` log column: what the core saw, in display units).
    Within ``[after_s, after_s + within_s]`` (to the end without ``within_s``) the quantity is captured at
    the first row within ``capture`` (default ``tolerance / 5``) of ``target`` (by ``t`` when given), and
    from there to the window's end its error must stay within ``tolerance``."""
    assert x.parameter is not None and x.target is not None and x.tolerance is not None
    if x.parameter == "height_m":
        values = -np.asarray(log["truth_d"], dtype=float)
    elif f"env_{x.parameter}" in log:
        values = np.asarray(log[f"env_{x.parameter}"], dtype=float)
    else:
        env = sorted(k.removeprefix("env_") for k in log if k.startswith("env_"))
        return Verdict(name, False, f"parameter {x.parameter!r} is not tracked; allowed: height_m, {', '.join(env)}")
    ts = log["t"]
    end = x.after_s + x.within_s if x.within_s is not None else math.inf
    sel = np.flatnonzero((ts >= x.after_s - 1e-9) & (ts <= end + 1e-9))
    capture = x.capture if x.capture is not None else x.tolerance / 5.0
    err = values[sel] - x.target
    inside = np.flatnonzero(np.abs(err) <= capture)
    if not inside.size:
        return Verdict(name, False, f"{x.parameter} never within {capture:g} of {x.target:g} (not captured)")
    c = int(inside[0])
    t_cap = float(ts[sel][c])
    if x.t is not None and t_cap > x.t + 1e-9:
        return Verdict(name, False, f"{x.parameter} captured at t={t_cap:.2f}, later than t={x.t}")
    after = err[c:]
    k = int(np.argmax(np.abs(after)))
    worst = float(after[k])
    return Verdict(name, abs(worst) <= x.tolerance,
                   f"{x.parameter} captured at t={t_cap:.2f}; largest error after capture {worst:+.2f} at "
                   f"t={float(ts[sel][c + k]):.2f} (allowed +-{x.tolerance:g})")


def evaluate_all(expectations: list[Expectation], events: list[dict[str, Any]], log: dict[str, np.ndarray],
                 metrics: dict[str, float]) -> list[Verdict]:
    return [evaluate(x, events, log, metrics) for x in expectations]


def finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None
