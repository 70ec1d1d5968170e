"""``merlin serve --autopilot-only``: serve as a plain autopilot under ``merlin guard`` (Merlin's own range,
envelope, link and low-battery judgements off; the offboard-loss failsafe the guard relies on kept)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import pytest

from merlin.commands.serve import options_from_args, register
from merlin.config.models import ActionName, MerlinConfig
from merlin.core.types import MonitorId
from merlin.serve.autopilot_only import MERLIN_ONLY_MONITORS

KEPT = [m for m in MonitorId if m not in MERLIN_ONLY_MONITORS]


def _opts(tmp_path: Path, *argv: str) -> Any:
    ap = argparse.ArgumentParser()
    register(ap.add_subparsers())
    return options_from_args(ap.parse_args(["serve", "--out", str(tmp_path / "out"), *argv]))


def test_autopilot_only_switches_off_the_guards_judgements_and_nothing_else(tmp_path: Path) -> None:
    cfg = _opts(tmp_path, "--autopilot-only").config
    default = MerlinConfig()
    assert not cfg.geofence.enabled
    for m in MERLIN_ONLY_MONITORS:
        r = cfg.arbiter.rules[m]
        assert (r.experimental, r.operator, r.trusted) == (ActionName.NONE,) * 3, m
    for m in KEPT:
        assert cfg.arbiter.rules[m] == default.arbiter.rules[m], m
    # the offboard-loss failsafe (what the guard checks as COM_OF_LOSS_T / COM_OBL_RC_ACT) still acts
    assert cfg.arbiter.rules[MonitorId.SETPOINT_STALE].experimental is ActionName.HOLD
    assert cfg.arbiter.rules[MonitorId.CONTROLLER_HEARTBEAT].experimental is ActionName.HOLD
    assert cfg.envelope == default.envelope and cfg.links == default.links


def test_without_the_option_serve_judges_as_merlin(tmp_path: Path) -> None:
    cfg = _opts(tmp_path).config
    assert cfg.geofence.enabled
    assert cfg.arbiter.rules[MonitorId.GEOFENCE].experimental is ActionName.RTL


def test_autopilot_only_over_a_file_keeps_its_timings_and_other_rules(tmp_path: Path) -> None:
    f = tmp_path / "serve.yaml"
    f.write_text("home: {lat_deg: 29.6516, lon_deg: -82.3248, alt_amsl_m: 30.0}\n"
                 "links: {offboard_loss_timeout_s: 0.8}\n"
                 "arbiter:\n  rules:\n"
                 "    geofence: {experimental: land, operator: land, trusted: land}\n"
                 "    setpoint_stale: {experimental: land, operator: none, trusted: none}\n")
    cfg = _opts(tmp_path, "--config", str(f), "--autopilot-only").config
    assert cfg.home.lat_deg == pytest.approx(29.6516)
    assert cfg.links.offboard_loss_timeout_s == pytest.approx(0.8)
    assert cfg.arbiter.rules[MonitorId.GEOFENCE].experimental is ActionName.NONE
    assert cfg.arbiter.rules[MonitorId.SETPOINT_STALE].experimental is ActionName.LAND
    assert not cfg.geofence.enabled
