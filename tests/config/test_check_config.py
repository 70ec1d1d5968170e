"""``merlin check-config``: exit 0 on a good file, with the SHA-256 and every table a reviewer needs."""

from __future__ import annotations

import json

import pytest

from merlin.cli import main
from merlin.config.loader import config_sha256, load_config
from merlin.config.models import ENVELOPE_PARAMETERS, MONITORS
from tests.config.paths import EXAMPLE_FILES, EXAMPLES


@pytest.mark.parametrize("path", EXAMPLE_FILES, ids=lambda p: p.name)
def test_good_file_exits_0_with_sha_and_envelope_table(path, capsys) -> None:
    assert main(["check-config", str(path)]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    cfg = load_config(path)
    assert f"sha256:        {config_sha256(cfg)}" in out
    assert repr(cfg.name) in out
    assert f"Envelope, stage {cfg.envelope.active_stage!r} (active)" in out
    assert "exceedance duration (s)" in out
    for p in ENVELOPE_PARAMETERS:
        assert f"\n{p} " in out
    for title in ("Envelope stages", "Geofence", "Geofence zones", "Watchdogs", "Arbiter table", "Handover"):
        assert f"\n{title}" in out


def _rows(out: str, title: str) -> list[list[str]]:
    block = out.split(f"\n{title}")[1].split("\n\n")[0].splitlines()
    return [line.split() for line in block[3:]]  # after title rest, underline, header


def test_text_tables_show_the_configured_values(capsys) -> None:
    assert main(["check-config", str(EXAMPLES / "expansion_campaign.yaml"), "--stage", "expanded"]) == 0
    out = capsys.readouterr().out
    active = {r[0]: r for r in _rows(out, "Envelope, stage 'conservative' (active)")}
    assert active["roll_deg"][:7] == ["roll_deg", "deg", "-20", "20", "0", "yes", "conservative"]
    expanded = {r[0]: r for r in _rows(out, "Envelope, stage 'expanded'")}
    assert expanded["roll_deg"][:7] == ["roll_deg", "deg", "-45", "45", "1", "yes", "expanded"]
    assert expanded["airspeed_mps"][5:7] == ["no", "conservative"]
    stages = {r[0]: r for r in _rows(out, "Envelope stages")}
    assert stages["expanded"][1:4] == ["intermediate", "conservative", "->"]
    arbiter = {r[0]: r for r in _rows(out, "Arbiter table")}
    assert set(arbiter) == set(MONITORS)
    assert arbiter["battery_critical"] == ["battery_critical", "land", "land", "land", "never"]


def test_json_output_is_the_same_information(capsys) -> None:
    path = EXAMPLES / "default.yaml"
    assert main(["check-config", str(path), "--json", "--stage", "expanded"]) == 0
    doc = json.loads(capsys.readouterr().out)
    cfg = load_config(path)
    assert doc["valid"] is True
    assert doc["sha256"] == config_sha256(cfg)
    assert doc["name"] == cfg.name and doc["active_stage"] == "conservative"
    assert [e["stage"] for e in doc["envelopes"]] == ["conservative", "expanded"]
    assert [e["active"] for e in doc["envelopes"]] == [True, False]
    for env in doc["envelopes"]:
        limits = cfg.envelope.resolve(env["stage"])
        assert [r["parameter"] for r in env["limits"]] == list(ENVELOPE_PARAMETERS)
        for r in env["limits"]:
            lim = limits[r["parameter"]]
            assert (r["min"], r["max"], r["duration_s"], r["enabled"]) == (
                lim.min,
                lim.max,
                lim.duration_s,
                lim.enabled,
            )
    assert {s["stage"]: s["extends"] for s in doc["stages"]} == {
        "conservative": None,
        "expanded": "conservative",
    }
    fence = doc["geofence"]
    assert fence["mode"] == "velocity_projection" and fence["margin_m"] == 8.0 and fence["sigma_k"] == 2.0
    assert fence["altitude_floor_m"] is None and fence["altitude_ceiling_m"] == 120.0
    assert [(z["kind"], z["name"]) for z in fence["zones"]] == [
        ("inclusion", "north field"),
        ("exclusion", "barn and yard"),
        ("exclusion", "radio mast"),
    ]
    mast = fence["zones"][2]
    assert mast["radius_m"] == 35.0
    # a circumscribed polygon: at least the circle's area, and its extent about its centre (+260 N, -190 E)
    assert mast["area_m2"] >= 3.14159 * 35.0**2
    assert mast["north_min_m"] <= 260.0 - 35.0 + 0.5 and mast["north_max_m"] >= 260.0 + 35.0 - 0.5
    assert fence["allowed_area_m2"] < fence["zones"][0]["area_m2"]
    assert doc["watchdogs"] == {
        "controller_heartbeat": 0.5,
        "setpoint_stale": 0.5,
        "rc_link": 1.0,
        "gcs_link": 5.0,
    }
    rules = {r["monitor"]: r for r in doc["arbiter"]["rules"]}
    assert rules["geofence"] == {
        "monitor": "geofence",
        "experimental": "rtl",
        "operator": "rtl",
        "trusted": "rtl",
        "clear": "on_request",
    }
    assert doc["arbiter"]["termination_enabled"] is False
    assert doc["handover"]["ack_timeout_s"] == cfg.handover.ack_timeout_s
    assert set(doc["handover"]) == set(type(cfg.handover).model_fields)


def test_disabled_fence_still_has_its_zones_checked_and_listed(tmp_path, capsys) -> None:
    src = (EXAMPLES / "default.yaml").read_text(encoding="utf-8")
    path = tmp_path / "disabled.yaml"
    path.write_text(
        src.replace("geofence:\n  enabled: true", "geofence:\n  enabled: false"), encoding="utf-8"
    )
    assert main(["check-config", str(path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["geofence"]["enabled"] is False and len(doc["geofence"]["zones"]) == 3
    bad = tmp_path / "disabled_bad.yaml"
    bad.write_text(
        "geofence:\n  enabled: false\n  inclusion_polygons:\n"
        "    - vertices_ne_m: [[0, 0], [0, 100], [100, 0], [100, 100]]\n",
        encoding="utf-8",
    )
    assert main(["check-config", str(bad)]) == 2
    assert "line 4: geofence.inclusion_polygons[0]: polygon is self-intersecting" in capsys.readouterr().err
