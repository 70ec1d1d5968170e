"""``merlin serve`` follows PX4 SITL's conventions: its default home, PX4_HOME_*, and ``--instance N`` with
PX4's port offsets and system id N + 1, so that two vehicles run side by side."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import pytest

from merlin.commands.serve import PX4_SITL_HOME, options_from_args, register, sitl_ports
from merlin.config.loader import ConfigError, load_config
from tests.ports import hold_exact_ports
from tests.serve.conftest import ROOT, STEP_TIMEOUT_S, ServeProc, stop, wait_ready


def _args(*argv: str) -> argparse.Namespace:
    ap = argparse.ArgumentParser()
    register(ap.add_subparsers())
    return ap.parse_args(["serve", *argv])


def _opts(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, *argv: str, env: dict[str, str] | None = None) -> Any:
    for var in ("PX4_HOME_LAT", "PX4_HOME_LON", "PX4_HOME_ALT"):
        monkeypatch.delenv(var, raising=False)
    for var, value in (env or {}).items():
        monkeypatch.setenv(var, value)
    return options_from_args(_args("--out", str(tmp_path / "out"), *argv))


def test_px4_sitl_ports_by_instance() -> None:
    # ROMFS/px4fmu_common/init.d-posix/px4-rc.mavlink
    assert sitl_ports(0) == {"gcs_bind_port": 18570, "gcs_port": 14550, "offboard_bind_port": 14580,
                             "offboard_port": 14540}
    assert sitl_ports(3) == {"gcs_bind_port": 18573, "gcs_port": 14550, "offboard_bind_port": 14583,
                             "offboard_port": 14543}
    assert sitl_ports(10)["offboard_port"] == 14549  # PX4 shares one remote port above instance 9


def test_no_arguments_start_at_px4_sitl_default_home_as_instance_0(monkeypatch: pytest.MonkeyPatch,
                                                                    tmp_path: Path) -> None:
    o = _opts(monkeypatch, tmp_path)
    h = o.config.home
    assert (h.lat_deg, h.lon_deg, h.alt_amsl_m) == PX4_SITL_HOME == (47.397742, 8.545594, 488.0)
    assert o.system_id == 1
    assert o.gcs.bind[1] == 18570 and o.gcs.remote[1] == 14550
    assert o.controller.bind[1] == 14580 and o.controller.remote[1] == 14540
    # the default fence is a circle about home: it moved with it
    assert o.config.geofence.inclusion_circles[0].center_ne_m == [0.0, 0.0]


def test_instance_offsets_ports_and_system_id_explicit_options_win(monkeypatch: pytest.MonkeyPatch,
                                                                   tmp_path: Path) -> None:
    o = _opts(monkeypatch, tmp_path, "--instance", "2")
    assert o.system_id == 3 and o.gcs.bind[1] == 18572 and o.controller.bind[1] == 14582
    assert o.controller.remote[1] == 14542 and o.gcs.remote[1] == 14550
    o = _opts(monkeypatch, tmp_path, "-i", "2", "--sysid", "42", "--offboard-port", "15000")
    assert o.system_id == 42 and o.controller.remote[1] == 15000 and o.controller.bind[1] == 14582
    with pytest.raises(ConfigError, match=r"--instance 255: allowed 0\.\.254"):
        _opts(monkeypatch, tmp_path, "--instance", "255")


def test_px4_home_environment_moves_home(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    o = _opts(monkeypatch, tmp_path, env={"PX4_HOME_LAT": "28.452386", "PX4_HOME_LON": "-13.867138",
                                          "PX4_HOME_ALT": "28.5"})
    assert (o.config.home.lat_deg, o.config.home.lon_deg, o.config.home.alt_amsl_m) == (28.452386, -13.867138, 28.5)
    with pytest.raises(ConfigError) as err:
        _opts(monkeypatch, tmp_path, env={"PX4_HOME_LAT": "north"})
    assert "PX4_HOME_LAT" in str(err.value) and "'north' is not a number" in str(err.value)
    with pytest.raises(ConfigError) as err:
        _opts(monkeypatch, tmp_path, env={"PX4_HOME_LAT": "95"})
    assert "PX4_HOME_LAT" in str(err.value) and "home.lat_deg = 95" in str(err.value)


def test_a_file_keeps_its_home_and_a_latlon_fence_refuses_to_be_left_behind(monkeypatch: pytest.MonkeyPatch,
                                                                           tmp_path: Path) -> None:
    cfg = ROOT / "examples" / "configs" / "default.yaml"  # its range is a polygon in latitude/longitude
    o = _opts(monkeypatch, tmp_path, "--config", str(cfg))
    assert o.config.home == load_config(cfg).home  # a file's home stands without PX4_HOME_*
    with pytest.raises(ConfigError) as err:
        _opts(monkeypatch, tmp_path, "--config", str(cfg), env={"PX4_HOME_LAT": "47.397742",
                                                                "PX4_HOME_LON": "8.545594"})
    text = str(err.value)
    assert "default.yaml" in text and "geofence.inclusion_polygons[0].vertices_deg" in text
    assert "PX4_HOME_LAT, PX4_HOME_LON" in text


@pytest.mark.integration
def test_two_instances_run_side_by_side_at_px4_sitl_home(tmp_path: Path) -> None:
    instances = (5, 6)
    ports = [sitl_ports(n) for n in instances]
    fixed = [p[k] for p in ports for k in ("offboard_port", "offboard_bind_port", "gcs_bind_port")]
    # PX4's own port numbers, not reserved ones: held against every other test using tests.ports (another
    # run of this test in another checkout) for as long as the two instances fly
    with hold_exact_ports(fixed) as held:
        if not held:
            pytest.skip("PX4 SITL's ports for instances 5 and 6 are in use on this machine")
        _two_instances(tmp_path, instances, ports)


def _two_instances(tmp_path: Path, instances: tuple[int, ...], ports: list[dict[str, int]]) -> None:
    import subprocess

    from pymavlink import mavutil

    procs = []
    for n in instances:
        out = tmp_path / f"v{n}"
        log = tmp_path / f"v{n}.log"
        cmd = [sys.executable, "-m", "merlin.cli", "serve", "--instance", str(n), "--out", str(out),
               "--duration", "120", "--quiet"]
        with log.open("w") as f:
            procs.append(ServeProc(subprocess.Popen(cmd, cwd=ROOT, stdout=f, stderr=subprocess.STDOUT, text=True),
                                   0, 0, out, log=log))
    try:
        for sp in procs:
            wait_ready(sp)
        for n, p in zip(instances, ports, strict=True):
            c = mavutil.mavlink_connection(f"udpin:127.0.0.1:{p['offboard_port']}", source_system=200 + n,
                                           dialect="common")
            hb = c.wait_heartbeat(timeout=STEP_TIMEOUT_S)
            assert hb is not None and hb.get_srcSystem() == n + 1, hb
            c.mav.heartbeat_send(18, 8, 0, 0, 0)
            home = c.recv_match(type="HOME_POSITION", blocking=True, timeout=STEP_TIMEOUT_S)
            if home is None:  # (HOME_POSITION is streamed slowly: ask for it, as MAVSDK does)
                c.mav.command_long_send(n + 1, 1, 512, 0, 242, 0, 0, 0, 0, 0, 0)
                home = c.recv_match(type="HOME_POSITION", blocking=True, timeout=STEP_TIMEOUT_S)
            assert home is not None
            assert (home.latitude, home.longitude) == (473977420, 85455940)
            assert home.altitude == pytest.approx(488000, abs=1)
            c.close()
    finally:
        for sp in procs:
            stop(sp)
