"""MAVLink 2 signing on the guard's links: with a key on the controller link, a controller that does not sign,
or signs with another key, reaches nothing (its arming, its requests, its setpoints are dropped before the
gate, and it never counts as alive, so it never gains authority); one that signs with the key is routed as
before, and what the guard sends it is signed (pymavlink verifies it)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from merlin.commands.guard import load
from merlin.guard.dialects import Dialect
from merlin.guard.endpoints import parse_endpoint
from merlin.guard.runner import Guard
from merlin.link.signing import write_key_file
from tests.guard.controller import Controller
from tests.guard.sim_autopilot import SimAutopilot
from tests.guard.test_guard_flight import CONFIG, wait_for
from tests.ports import reserve_port

pytestmark = pytest.mark.integration

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))


@pytest.mark.parametrize("controller_key", [None, OTHER_KEY, KEY], ids=["unsigned", "wrong-key", "signed"])
def test_only_a_controller_signing_with_the_key_reaches_the_autopilot(controller_key: bytes | None,
                                                                       tmp_path: Path) -> None:
    ap_port, ctl_port = reserve_port(), reserve_port()
    sim = SimAutopilot(Dialect.PX4, ap_port).start()
    cfg_file = tmp_path / "guard.yaml"
    cfg_file.write_text(CONFIG)
    cfg, gcfg = load(str(cfg_file))
    guard = Guard(cfg, gcfg, parse_endpoint(f"udpin:127.0.0.1:{ap_port}"), parse_endpoint(f"udpin:127.0.0.1:{ctl_port}"),
                  None, tmp_path / "out", signing_keys={"controller": KEY})
    guard.start()
    thread = threading.Thread(target=guard.run, daemon=True)
    thread.start()
    ctl = Controller(ctl_port, signing_key=controller_key).start()
    try:
        # the guard answers on the controller link only once it heard verified MAVLink from there (udpin), so
        # an unsigned controller does not even see the autopilot
        deadline = time.monotonic() + 4.0
        while time.monotonic() < deadline and not sim.armed:
            ctl.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            time.sleep(0.3)
        ctl.streaming = True
        time.sleep(1.5)
        ctl.set_mode(6.0, 0.0)  # PX4 OFFBOARD: the authority request
        time.sleep(1.0)
        if controller_key == KEY:
            assert sim.armed and sim.track.setpoints_t, "a signing controller was not routed"
            wait_for(lambda: ctl.mode() is not None, 5, "the autopilot's HEARTBEAT, signed by the guard")
            assert ctl.m.signing.secret_key == KEY
        else:
            assert not sim.armed and sim.track.setpoints_t == [] and sim.mode != sim.offboard
            assert guard.inputs.heartbeat_t is None  # never alive for the core: never a grant
            assert guard.decision is not None and guard.decision.authority.name != "EXPERIMENTAL"
            dropped = sum(n for k, n in guard.counts.items() if k.startswith("dropped: controller frame"))
            assert dropped > 0 and ctl.heartbeats == []
    finally:
        ctl.stop()
        guard.stop()
        thread.join(timeout=5)
        guard.close()
        sim.stop()


def test_a_signing_key_file_that_cannot_be_read_is_refused_naming_the_option(tmp_path: Path) -> None:
    import subprocess
    import sys

    from tests.guard.test_guard_flight import ROOT

    bad = tmp_path / "bad.key"
    bad.write_text("not a key\n")
    good = tmp_path / "good.key"
    write_key_file(good, KEY)
    proc = subprocess.run([sys.executable, "-m", "merlin.cli", "guard", "--autopilot", "udpin:127.0.0.1:1",
                           "--controller", "udpin:127.0.0.1:2", "--signing-key", str(good),
                           "--controller-signing-key", str(bad)], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "--controller-signing-key" in proc.stderr and str(bad) in proc.stderr


def test_what_the_guard_signs_verifies_in_pymavlink_and_a_frame_of_another_key_is_signed_again() -> None:
    from merlin.link import autopilot_wire as w
    from merlin.link.signing import SignatureCheck, SigningState

    m = mav.MAVLink(None, 1, 191)
    raw = bytes(m.heartbeat_encode(18, 8, 0, 0, 4).pack(m))
    now = time.time()
    signer = w.LinkSigner(KEY, link_id=2)
    out = signer.sign(raw, now)
    assert out is not None and len(out) == len(raw) + 13
    rx = mav.MAVLink(None, 0, 0)
    rx.signing.secret_key = KEY
    assert len(rx.parse_buffer(out) or []) == 1 and rx.signing.goodsig_count == 1
    assert signer.sign(out, now) is out  # already signed with this key: forwarded as it came
    other = w.LinkSigner(OTHER_KEY).sign(out, now)
    assert other is not None
    frames, _ = w.frame_splitter().feed(other, final=True)
    assert SigningState(OTHER_KEY).check(frames[0]) is SignatureCheck.OK
    assert SigningState(KEY).check(frames[0]) is SignatureCheck.BAD_SIGNATURE
    again = signer.sign(other, now)
    assert again is not None and again != other
    frames, _ = w.frame_splitter().feed(again, final=True)
    assert SigningState(KEY).check(frames[0]) is SignatureCheck.OK
    # timestamps strictly increase, so a receiver's replay rule never drops the guard's own frames
    assert int.from_bytes(again[-12:-6], "little") > int.from_bytes(out[-12:-6], "little")
    assert signer.sign(b"\xfe" + raw[1:], now) is None and signer.unsignable == 1
