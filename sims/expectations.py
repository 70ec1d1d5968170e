"""Expectations: what a scenario says must be true after the run, checked against its events, log and metrics."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from merlin.core.types import Authority, Behavior
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


def _matches(e: dict[str, Any], x: Expectation) -> bool:
    if x.reason is not None and e.get("reason") != x.reason:
        return False
    if x.parameter is not None and e.get("reason_detail", {}).get("parameter") != x.parameter:
        return False
    if e["t"] < x.after_s - 1e-9:
        return False
    if x.duration_s is not None and abs(e.get("reason_detail", {}).get("duration_s", math.nan) - x.duration_s) > 1e-6:
        return False
    return x.not_before_s is None or e["t"] >= x.not_before_s - 1e-9


def _describe(x: Expectation) -> str:
    if x.name:
        return x.name
    parts = [x.type]
    for k in ("t", "authority", "behavior", "reason", "parameter", "event", "after_s", "within_s", "m", "mps"):
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
        armed = bool(log["armed"][-1] > 0.5) if len(log["armed"]) else False
        return Verdict(name, not armed, f"armed at the end: {armed}")
    if kind == "max_command_jump":
        lim = x.mps if x.mps is not None else 0.5
        j = metrics["max_authority_change_command_jump_mps"]
        return Verdict(name, j <= lim, f"largest command step at a change of authority {j:.3f} m/s (allowed {lim})")
    return Verdict(name, False, f"unknown expectation type {kind!r}")  # unreachable: the model validates types


def evaluate_all(expectations: list[Expectation], events: list[dict[str, Any]], log: dict[str, np.ndarray],
                 metrics: dict[str, float]) -> list[Verdict]:
    return [evaluate(x, events, log, metrics) for x in expectations]


def finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None
