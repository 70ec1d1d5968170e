"""The MAVSDK-Python controller (standard Offboard calls only) flies against ``merlin serve`` unchanged."""

from __future__ import annotations

import pytest

from tests.serve.conftest import ServeProc, lines_until

pytestmark = pytest.mark.integration


def test_mavsdk_offboard_flight_then_envelope_revocation_seen_as_mode_change(serve: ServeProc) -> None:
    # 12 m/s north is beyond the conservative envelope's vel_n_mps limit (8 m/s for 0.5 s): Merlin revokes
    ctl = serve.spawn("-m", "experimental_controllers.mavsdk_offboard", "--url",
                      f"udpin://0.0.0.0:{serve.ctl_port}", "--speed", "12", "--fly-s", "40", "--timeout", "60")
    out = lines_until(ctl, "mode left OFFBOARD", timeout_s=150)
    text = "\n".join(x for x in out if x.startswith("mavsdk_offboard"))
    for step in ("connected", "armed", "airborne", "mode OFFBOARD", "mode left OFFBOARD"):
        assert f"mavsdk_offboard: {step}" in text, text
    left = next(x for x in out if "mode left OFFBOARD" in x)
    assert left.split(": ")[-1] in ("RETURN_TO_LAUNCH", "HOLD", "LAND")
    revoked = [e for e in serve.events() if e["type"] == "revoked"]  # written before the mode changes
    assert revoked and revoked[0]["reason"] == "envelope"
    # flying 12 m/s north: the pitch needed to accelerate or the speed itself leaves the envelope
    assert revoked[0]["reason_detail"]["parameter"] in ("pitch_deg", "vel_n_mps")
