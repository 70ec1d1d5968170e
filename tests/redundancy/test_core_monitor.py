"""The core's ``nav_redundancy`` monitor: what the redundancy stage reports (``Inputs.redundancy``) has an
effect. Down to simplex it warns without changing authority by default; the rule table can make it an
RTL or a LAND; ``redundancy.warn_at: duplex`` trips it one level earlier; a vehicle that does not report
its redundancy (``redundancy.enabled: false``) has no such row and nothing trips."""

from __future__ import annotations

from dataclasses import dataclass, replace

from merlin.config.models import MerlinConfig
from merlin.core.types import Authority, Behavior, Decision, EventKind, Inputs, ReasonCode, RedundancyReport
from tests.core.harness import Harness, events_of

SIMPLEX = RedundancyReport(1, 0.5, "imu SIMPLEX (lanes 0, 1 isolated)")
DUPLEX = RedundancyReport(2, 0.8, "gps DUPLEX (lane 1 isolated)")


def _cfg(**redundancy: object) -> MerlinConfig:
    data: dict[str, object] = {"redundancy": {"enabled": True, **redundancy}}
    return MerlinConfig.model_validate(data)


class _ReportingCore:
    """The harness's core with the redundancy report of the harness added to every tick's inputs."""

    def __init__(self, core: object, h: ReportingHarness) -> None:
        self._core, self._h = core, h

    def step(self, now: float, inputs: Inputs) -> Decision:
        return self._core.step(now, replace(inputs, redundancy=self._h.report))  # type: ignore[attr-defined]


@dataclass
class ReportingHarness(Harness):
    report: RedundancyReport | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        self.core = _ReportingCore(self.core, self)  # type: ignore[assignment]


def _experimental(h: ReportingHarness) -> None:
    h.airborne()
    h.run(1.5)
    h.grant()


def test_simplex_warns_once_and_keeps_authority_by_default() -> None:
    h = ReportingHarness(cfg=_cfg())
    _experimental(h)
    h.report = RedundancyReport(3, 1.0, "")
    assert h.run(0.5).authority is Authority.EXPERIMENTAL
    h.report = DUPLEX
    d = h.tick()
    assert not events_of(d, EventKind.WARNING), "duplex is not a warning at the default warn_at: simplex"
    h.report = SIMPLEX
    d = h.tick()
    warnings = events_of(d, EventKind.WARNING)
    assert len(warnings) == 1
    r = warnings[0].reason
    assert r.code is ReasonCode.REDUNDANCY_DEGRADED and r.monitor == "nav_redundancy"
    assert "SIMPLEX" in r.text and "imu" in r.text and "0.50" in r.text
    assert r.value == 1.0 and r.limit == 2.0
    status = next(m for m in d.monitors if m.name == "nav_redundancy")
    assert status.tripped
    later = h.run(2.0)
    assert later.authority is Authority.EXPERIMENTAL and later.revocations == 0
    assert not any(events_of(x, EventKind.WARNING) for x in h.history[-790:]), "warned once, not every tick"


def test_rule_table_can_make_it_an_rtl() -> None:
    cfg = MerlinConfig.model_validate(
        {
            "redundancy": {"enabled": True},
            "arbiter": {
                "rules": {"nav_redundancy": {"experimental": "rtl", "operator": "warn", "trusted": "rtl"}}
            },
        }
    )
    h = ReportingHarness(cfg=cfg)
    _experimental(h)
    h.report = SIMPLEX
    d = h.tick()
    revoked = events_of(d, EventKind.REVOKED)
    assert revoked and revoked[0].reason.code is ReasonCode.REDUNDANCY_DEGRADED
    assert d.authority is Authority.TRUSTED and d.behavior is Behavior.RTL


def test_warn_at_duplex_trips_one_level_earlier() -> None:
    h = ReportingHarness(cfg=_cfg(warn_at="duplex"))
    _experimental(h)
    h.report = DUPLEX
    d = h.tick()
    w = events_of(d, EventKind.WARNING)
    assert len(w) == 1 and "DUPLEX" in w[0].reason.text and "gps" in w[0].reason.text
    assert d.authority is Authority.EXPERIMENTAL


def test_clears_when_redundancy_returns() -> None:
    h = ReportingHarness(cfg=_cfg())
    _experimental(h)
    h.report = SIMPLEX
    h.tick()
    h.report = RedundancyReport(3, 1.0, "")  # e.g. a lane reintegrated (reintegration_s)
    d = h.tick()
    cleared = events_of(d, EventKind.MONITOR_CLEARED)
    assert [e.reason.monitor for e in cleared] == ["nav_redundancy"]


def test_no_row_and_no_trip_when_the_vehicle_reports_no_redundancy() -> None:
    h = ReportingHarness(cfg=MerlinConfig())  # redundancy.enabled: false
    _experimental(h)
    h.report = SIMPLEX
    d = h.run(0.5)
    assert not any(m.name == "nav_redundancy" for m in d.monitors)
    assert not any(events_of(x, EventKind.WARNING) for x in h.history[-200:])
    # and with the row but no report (the edge sends none): nothing trips either
    h2 = ReportingHarness(cfg=_cfg())
    _experimental(h2)
    d2 = h2.run(0.5)
    assert not next(m for m in d2.monitors if m.name == "nav_redundancy").tripped
