"""The parameter protocol against a ``merlin serve`` subprocess, as a ground station uses it: limits edited on the
ground go through the configuration models into the trusted core, the logs and ``effective_config.yaml``; in
flight, with ``--params-locked`` and on the controller's link they are refused with the value in force."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import pytest

from merlin.config.loader import config_sha256, load_config
from merlin.config.models import ENVELOPE_PARAMETERS, MerlinConfig
from tests.serve.conftest import (
    STEP_TIMEOUT_S,
    ServeProc,
    arm_and_takeoff,
    gcs_connection,
    start_serve,
    stop,
    wait_for,
)

pytestmark = pytest.mark.integration

REAL32, INT32 = 9, 6
ROLL = ENVELOPE_PARAMETERS.index("roll_deg")  # MERLIN_ENVELOPE_STATUS.parameter
AIRSPEED = ENVELOPE_PARAMETERS.index("airspeed_mps")
DISABLED = 0  # MERLIN_ENVELOPE_STATE



def _built_in() -> MerlinConfig:
    """What serve flies without --config: the built-in configuration at PX4 SITL's default home."""
    from merlin.commands.serve import sitl_home

    return sitl_home(MerlinConfig(), None, {})

def _read(m: Any, param: str) -> Any:
    m.mav.param_request_read_send(1, 1, param.encode(), -1)
    return wait_for(m, lambda x: x.get_type() == "PARAM_VALUE" and x.param_id == param)


def _statustext(m: Any, prefix: str, timeout_s: float = STEP_TIMEOUT_S) -> str | None:
    """The next STATUSTEXT starting with ``prefix``, its chunks (MAVLink 2 ``id``/``chunk_seq``) joined."""
    first = wait_for(m, lambda x: x.get_type() == "STATUSTEXT" and x.chunk_seq == 0 and x.text.startswith(prefix),
                     timeout_s)
    if first is None:
        return None
    text = first.text
    while first.id != 0 and len(text) % 50 == 0:  # a chunk shorter than 50 characters is the last
        more = wait_for(m, lambda x: x.get_type() == "STATUSTEXT" and x.id == first.id and x.chunk_seq > 0, 5.0)
        if more is None:
            break
        text += more.text
    return text


def _set(m: Any, param: str, value: float, param_type: int = REAL32) -> tuple[Any, str | None]:
    """PARAM_SET, then the PARAM_VALUE answering it and the STATUSTEXT saying what became of it."""
    m.mav.param_set_send(1, 1, param.encode(), value, param_type)
    pv = wait_for(m, lambda x: x.get_type() == "PARAM_VALUE" and x.param_id == param)
    return pv, _statustext(m, f"Merlin: {param} ")


def _roll_status(m: Any, pred: Any) -> Any:
    return wait_for(m, lambda x: x.get_type() == "MERLIN_ENVELOPE_STATUS" and x.parameter == ROLL and pred(x))


def test_limits_set_on_the_ground_are_flown_and_refused_in_flight(serve: ServeProc) -> None:
    m = gcs_connection(serve.gcs_port)
    before = _read(m, "ENV_ROLL_MAX")
    assert before is not None and before.param_value == pytest.approx(30.0)

    # on the ground, disarmed: the new value is echoed, read back, and said
    pv, text = _set(m, "ENV_ROLL_MAX", 25.0)
    assert pv is not None and pv.param_value == pytest.approx(25.0)
    assert (pv.param_index, pv.param_count, pv.param_type) == (before.param_index, before.param_count, REAL32)
    assert text == "Merlin: ENV_ROLL_MAX set 30 -> 25"
    again = _read(m, "ENV_ROLL_MAX")
    assert again is not None and again.param_value == pytest.approx(25.0)

    # what the configuration models refuse is refused, saying what is allowed; so are a wrong type and NaN
    pv, text = _set(m, "ENV_ROLL_DUR", 700.0)
    assert pv is not None and pv.param_value == pytest.approx(0.0)
    assert text == ("Merlin: ENV_ROLL_DUR 700 refused: roll_deg.duration_s: Input should be less than or equal"
                    " to 600")
    pv, text = _set(m, "ENV_ROLL_MAX", -45.0)
    assert pv is not None and pv.param_value == pytest.approx(25.0)
    assert text == "Merlin: ENV_ROLL_MAX -45 refused: roll_deg: min (-30.0) must not exceed max (-45.0)"
    pv, text = _set(m, "ENV_ROLL_MAX", 20.0, INT32)
    assert pv is not None and pv.param_value == pytest.approx(25.0)
    assert text == "Merlin: ENV_ROLL_MAX type 6 refused: is REAL32 (9)"
    m.mav.param_set_send(1, 1, b"ENV_ROLL_MAX", math.nan, REAL32)  # dropped by the link as malformed
    assert wait_for(m, lambda x: x.get_type() == "PARAM_VALUE" and x.param_id == "ENV_ROLL_MAX", 2.0) is None

    # the trusted core judges by the new limit: roll ~0 deg on the ground is outside [5, 25] deg, and the
    # core's envelope monitor times the exceedance (MERLIN_ENVELOPE_STATUS.exceedance_elapsed is its timer)
    inside = _roll_status(m, lambda x: x.max == pytest.approx(25.0))
    assert inside is not None and inside.exceedance_elapsed == 0.0 and inside.min == pytest.approx(-30.0)
    pv, text = _set(m, "ENV_ROLL_MIN", 5.0)
    assert pv is not None and pv.param_value == pytest.approx(5.0) and text == "Merlin: ENV_ROLL_MIN set -30 -> 5"
    outside = _roll_status(m, lambda x: x.min == pytest.approx(5.0) and x.exceedance_elapsed > 0.5)
    assert outside is not None, "the core does not time the roll exceedance against the new minimum"
    pv, text = _set(m, "ENV_ROLL_MIN", -30.0)
    assert pv is not None and pv.param_value == pytest.approx(-30.0)
    assert _roll_status(m, lambda x: x.min == pytest.approx(-30.0) and x.exceedance_elapsed == 0.0) is not None
    # switching a limit on and off changes how many limits the core monitors; it keeps ticking
    for on in (1.0, 0.0):
        pv, text = _set(m, "ENV_AIRSPD_EN", on)
        assert pv is not None and pv.param_value == on
        state = wait_for(m, lambda x: x.get_type() == "MERLIN_ENVELOPE_STATUS" and x.parameter == AIRSPEED)
        assert state is not None and (state.state != DISABLED) == bool(on)

    # the experimental controller's link may read, never write
    from pymavlink import mavutil

    ctl = mavutil.mavlink_connection(f"udpin:127.0.0.1:{serve.ctl_port}", source_system=42, source_component=191)
    try:
        assert ctl.wait_heartbeat(timeout=STEP_TIMEOUT_S) is not None
        pv, text = _set(ctl, "ENV_ROLL_MAX", 45.0)
        assert pv is not None and pv.param_value == pytest.approx(25.0)
        assert text == "Merlin: ENV_ROLL_MAX read-only on the controller link"
    finally:
        ctl.close()

    # in flight: refused, the value in force unchanged
    arm_and_takeoff(m)
    pv, text = _set(m, "ENV_ROLL_MAX", 45.0)
    assert pv is not None and pv.param_value == pytest.approx(25.0)
    assert text == "Merlin: ENV_ROLL_MAX read-only while armed"
    after = _read(m, "ENV_ROLL_MAX")
    assert after is not None and after.param_value == pytest.approx(25.0)
    m.close()
    stop(serve)

    events = serve.events()
    start = next(e for e in events if e["type"] == "serve_start")
    assert start["config_sha256"] == config_sha256(_built_in())
    assert start["params"] == "writable on the ground (gcs link)"
    sets = [(e["param"], e["result"], e["value"], e["in_force"], e["link"]) for e in events if e["type"] == "param_set"]
    assert sets == [
        ("ENV_ROLL_MAX", "accepted", 25.0, 25.0, "gcs"), ("ENV_ROLL_DUR", "refused", 700.0, 0.0, "gcs"),
        ("ENV_ROLL_MAX", "refused", -45.0, 25.0, "gcs"), ("ENV_ROLL_MAX", "refused", 20.0, 25.0, "gcs"),
        ("ENV_ROLL_MIN", "accepted", 5.0, 5.0, "gcs"), ("ENV_ROLL_MIN", "accepted", -30.0, -30.0, "gcs"),
        ("ENV_AIRSPD_EN", "accepted", 1.0, 1.0, "gcs"), ("ENV_AIRSPD_EN", "accepted", 0.0, 0.0, "gcs"),
        ("ENV_ROLL_MAX", "refused", 45.0, 25.0, "controller"), ("ENV_ROLL_MAX", "refused", 45.0, 25.0, "gcs")]
    changes = [e for e in events if e["type"] == "config_changed"]
    assert [(e["source"], e["param"], e["old"], e["new"]) for e in changes] == [
        ("PARAM_SET", "ENV_ROLL_MAX", 30.0, 25.0), ("PARAM_SET", "ENV_ROLL_MIN", -30.0, 5.0),
        ("PARAM_SET", "ENV_ROLL_MIN", 5.0, -30.0), ("PARAM_SET", "ENV_AIRSPD_EN", 0.0, 1.0),
        ("PARAM_SET", "ENV_AIRSPD_EN", 1.0, 0.0)]
    # the hashes chain from the configuration served at start to the file written last
    assert changes[0]["old_sha256"] == start["config_sha256"]
    assert all(a["new_sha256"] == b["old_sha256"] for a, b in itertools.pairwise(changes))
    # and name the content: ENV_ROLL_MIN back to -30 is the configuration of the first change again
    assert changes[2]["new_sha256"] == changes[0]["new_sha256"] != changes[1]["new_sha256"] != start["config_sha256"]
    flown = load_config(serve.out / "effective_config.yaml")
    assert config_sha256(flown) == changes[-1]["new_sha256"]
    roll = flown.envelope.effective()["roll_deg"]
    assert (roll.min, roll.max, roll.duration_s) == (-30.0, 25.0, 0.0)
    stop_rec = next(e for e in events if e["type"] == "serve_stop")
    assert stop_rec["links"]["gcs"]["rejected"] == {"non_finite": 1}
    assert not [e for e in events if e["type"] == "serve_error"]


def test_params_locked_refuses_every_write(tmp_path: Path) -> None:
    sp = start_serve(tmp_path, "--params-locked")
    try:
        m = gcs_connection(sp.gcs_port)
        pv, text = _set(m, "ENV_ROLL_MAX", 25.0)
        assert pv is not None and pv.param_value == pytest.approx(30.0)
        assert text == "Merlin: ENV_ROLL_MAX read-only (locked)"
        m.close()
    finally:
        stop(sp)
    events = sp.events()
    assert next(e for e in events if e["type"] == "serve_start")["params"] == "locked"
    assert not [e for e in events if e["type"] == "config_changed"]
    assert config_sha256(load_config(sp.out / "effective_config.yaml")) == config_sha256(_built_in())


def test_the_configuration_can_lock_the_parameters(tmp_path: Path) -> None:
    # no process: the command-line option and the configuration key meet in options_from_args
    from merlin.cli import build_parser
    from merlin.commands.serve import options_from_args

    cfg = tmp_path / "site.yaml"
    cfg.write_text("links:\n  params_locked: true\n", encoding="utf-8")
    for extra in ([], ["--params-locked"]):
        args = build_parser().parse_args(["serve", "--config", str(cfg), "--out", str(tmp_path / "o"), *extra])
        assert options_from_args(args).params_locked
    args = build_parser().parse_args(["serve", "--out", str(tmp_path / "o")])
    assert not options_from_args(args).params_locked
