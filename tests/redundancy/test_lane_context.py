"""What every autopilot lane reads beside its own sensors (:func:`merlin.redundancy.lanes.lane_context`): the
failsafe is the core's decision's, never re-derived from the rule table."""

from __future__ import annotations

from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.types import (
    Action,
    Authority,
    Behavior,
    Command,
    CommandKind,
    Decision,
    MonitorId,
    MonitorStatus,
)
from merlin.redundancy.lanes import lane_context

CFG = build_core_config(MerlinConfig())


def _decision(failsafe: Action, *monitors: MonitorStatus) -> Decision:
    return Decision(1.0, Authority.TRUSTED, Behavior.HOLD, Command(CommandKind.VELOCITY, Authority.TRUSTED),
                    monitors, (), True, failsafe=failsafe)


def test_the_lanes_read_the_decisions_failsafe() -> None:
    # no monitor tripped in the statuses: the failsafe is the decision's word alone
    assert not lane_context(_decision(Action.RTL), CFG, 1.0).no_failsafe
    assert not lane_context(_decision(Action.HOLD), CFG, 1.0).no_failsafe
    # a tripped monitor whose rule is only a warning (or nothing) is not a failsafe
    rc = MonitorStatus(MonitorId.RC_LINK, True)
    assert lane_context(_decision(Action.WARN, rc), CFG, 1.0).no_failsafe
    assert lane_context(_decision(Action.NONE), CFG, 1.0).no_failsafe


def test_the_data_link_and_battery_flags() -> None:
    gcs = MonitorStatus(MonitorId.GCS_LINK, True)
    ctx = lane_context(_decision(Action.RTL, gcs), CFG, 0.5)
    assert not ctx.data_link_ok and ctx.battery_ok
    ctx = lane_context(_decision(Action.NONE, MonitorStatus(MonitorId.GCS_LINK, False)), CFG, 0.0)
    assert ctx.data_link_ok and not ctx.battery_ok
