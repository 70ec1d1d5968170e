"""The ``links:`` configuration section: validation, key files relative to the configuration file, command-line
overrides, and a ``merlin serve`` subprocess that enforces what the file says."""

from __future__ import annotations

import base64
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError

from merlin.cli import main
from merlin.config.loader import ConfigError, load_config_text
from merlin.config.models import LinksConfig, signing_key_from_file_bytes
from merlin.link.security import DEFAULT_SIGNED_CLASSES
from merlin.serve.link_security import KeyFileProblem, LinkOverrides, link_setups
from tests.serve.conftest import command, gcs_connection, start_serve, stop

KEY = bytes(range(32))


def _cfg_file(tmp_path: Path, links_yaml: str) -> Path:
    p = tmp_path / "cfg" / "site.yaml"
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text("merlin_config_version: 1\nlinks:\n" + links_yaml, encoding="utf-8")
    return p


# ------------------------------------------------------------------------------------------ the model


@given(st.binary(min_size=32, max_size=32), st.sampled_from(["hex", "b64", "raw"]), st.sampled_from(["", "\n", " \n"]))
def test_every_documented_key_file_form_reads_back_the_key(key: bytes, form: str, ws: str) -> None:
    data = {"hex": key.hex().encode(), "b64": base64.b64encode(key), "raw": key}[form]
    if form != "raw":
        data += ws.encode()
    assert signing_key_from_file_bytes(data) == key


@given(st.binary(max_size=100).filter(lambda b: len(b) != 32))
def test_anything_else_is_not_a_key(data: bytes) -> None:
    text = data.strip()
    if len(text) in (44, 64):  # may genuinely be hex or base64 of 32 bytes: not the point of this property
        return
    with pytest.raises(ValueError, match="64 hex digits, 44 base64 characters or exactly 32 raw bytes"):
        signing_key_from_file_bytes(data)


def test_allow_list_ids_are_checked_with_the_key_path_and_value() -> None:
    with pytest.raises(ConfigError) as err:
        load_config_text("links:\n  gcs:\n    allowed_system_ids: [255, 0, 256]\n    allowed_component_ids: [-1]\n",
                         "site.yaml")
    text = str(err.value)
    assert "site.yaml" in text
    assert "line 3: links.gcs.allowed_system_ids.1: Input should be greater than or equal to 1; value 0" in text
    assert "links.gcs.allowed_system_ids.2: Input should be less than or equal to 255; value 256" in text
    assert "links.gcs.allowed_component_ids.0: Input should be greater than or equal to 0; value -1" in text


def test_require_signed_without_any_key_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"links\.controller\.signing: .*require_signed is true but there is no"
                                          r" key_file"):
        load_config_text("links:\n  controller:\n    signing:\n      require_signed: true\n", "site.yaml")
    # with provisioning allowed it is a valid (fail-closed until provisioned) configuration
    load_config_text("links:\n  controller:\n    signing:\n      require_signed: true\n"
                     "      allow_unsigned_provisioning: true\n", "site.yaml")


def test_key_file_is_checked_relative_to_the_config_directory(tmp_path: Path) -> None:
    data = {"controller": {"signing": {"key_file": "keys/ctl.key", "require_signed": True}}}
    with pytest.raises(ValidationError, match=r"key_file 'keys/ctl.key': .*keys/ctl.key' does not exist"):
        LinksConfig.model_validate(data, context={"config_dir": tmp_path})
    (tmp_path / "keys").mkdir()
    (tmp_path / "keys" / "ctl.key").write_text("not a key")
    with pytest.raises(ValidationError, match=r"key_file 'keys/ctl.key': a signing key file holds 64 hex digits"):
        LinksConfig.model_validate(data, context={"config_dir": tmp_path})
    (tmp_path / "keys" / "ctl.key").write_text(KEY.hex())
    LinksConfig.model_validate(data, context={"config_dir": tmp_path})
    # without a directory (check-config of a file elsewhere, the built-in default) only the form is checked
    LinksConfig.model_validate({"controller": {"signing": {"key_file": "elsewhere.key"}}})


# ------------------------------------------------------------------------------------- policies, overrides


def test_policies_follow_the_file_and_the_command_line_overrides_it(tmp_path: Path) -> None:
    (tmp_path / "ctl.key").write_text(KEY.hex())
    links = LinksConfig.model_validate({
        "controller": {"signing": {"key_file": "ctl.key", "require_signed": True}, "allowed_system_ids": [42],
                       "allowed_component_ids": [191]},
        "gcs": {"allowed_system_ids": [255]},
    })
    s = link_setups(links, tmp_path)
    ctl, gcs = s["controller"].policy, s["gcs"].policy
    assert ctl.signing_key == KEY and ctl.required_classes(True) == DEFAULT_SIGNED_CLASSES
    assert ctl.allowed_system_ids == {42} and ctl.allowed_component_ids == {191}
    assert s["controller"].key_file == tmp_path / "ctl.key"
    assert gcs.signing_key is None and gcs.required_classes(False) == frozenset()
    assert gcs.allowed_system_ids == {255} and gcs.allowed_component_ids is None

    other = tmp_path / "other.key"
    other.write_bytes(bytes(32))
    s = link_setups(links, tmp_path, LinkOverrides(key_file=other, gcs_system_ids=frozenset({7})))
    for name in ("controller", "gcs"):
        assert s[name].policy.signing_key == bytes(32)
        assert s[name].policy.required_classes(True) == DEFAULT_SIGNED_CLASSES
    assert s["gcs"].policy.allowed_system_ids == {7}
    assert s["controller"].policy.allowed_system_ids == {42}  # not overridden


def test_a_missing_key_file_names_the_key_unless_provisioning_will_write_it(tmp_path: Path) -> None:
    links = LinksConfig.model_validate({"gcs": {"signing": {"key_file": "gcs.key", "require_signed": True}}})
    with pytest.raises(KeyFileProblem, match=r"links\.gcs\.signing\.key_file: .*gcs\.key' does not exist"):
        link_setups(links, tmp_path)
    s = link_setups(links, tmp_path, LinkOverrides(allow_unsigned_provisioning=True))
    assert s["gcs"].policy.signing_key is None and s["gcs"].key_file == tmp_path / "gcs.key"
    # fail closed: nothing of the signed classes is accepted until a key is provisioned
    assert s["gcs"].policy.required_classes(False) == DEFAULT_SIGNED_CLASSES


def test_serve_refuses_a_config_whose_key_file_is_missing(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    cfg = _cfg_file(tmp_path, "  controller:\n    signing:\n      key_file: missing.key\n")
    rc = main(["serve", "--config", str(cfg), "--duration", "0.1", "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2
    assert str(cfg) in err and "links.controller.signing" in err and "missing.key' does not exist" in err


# ------------------------------------------------------------------------------------------ in serve


@pytest.mark.integration
def test_serve_enforces_the_links_section(tmp_path: Path) -> None:
    cfg = _cfg_file(tmp_path, "  gcs:\n    signing:\n      key_file: keys/gcs.key\n      require_signed: true\n"
                              "    allowed_system_ids: [255]\n")
    (cfg.parent / "keys").mkdir()
    (cfg.parent / "keys" / "gcs.key").write_text(base64.b64encode(KEY).decode() + "\n")
    sp = start_serve(tmp_path, "--config", str(cfg))
    try:
        m = gcs_connection(sp.gcs_port)
        assert command(m, 400, 1.0, timeout_s=3.0) is None  # unsigned ARM: dropped, no answer
        m.setup_signing(KEY, sign_outgoing=True)
        ack = command(m, 400, 1.0)
        assert ack is not None and ack.result == 0, "a signed ARM from an allowed system is accepted"
        ack = command(m, 400, 0.0)  # disarm again, still signed
        assert ack is not None and ack.result == 0
        from pymavlink import mavutil

        intruder = mavutil.mavlink_connection(f"udpout:127.0.0.1:{_gcs_local_port(sp)}", source_system=77,
                                              source_component=190)
        intruder.setup_signing(KEY, sign_outgoing=True)  # even with the key: system 77 is not on the list
        intruder.mav.command_long_send(1, 1, 400, 0, 1.0, 0, 0, 0, 0, 0, 0)
        # the intruder's datagram is queued on the vehicle's GCS socket before this one, so the answer to this
        # signed command proves the intruder's was read (and refused) first; a heartbeat proved nothing
        ack = command(m, 400, 0.0)
        assert ack is not None and ack.result == 0
    finally:
        stop(sp)
    ev = sp.events()
    start = next(e for e in ev if e["type"] == "serve_start")
    sec = start["links"]["gcs"]["security"]
    assert sec["signing_key"] == "loaded" and sec["allowed_system_ids"] == [255]
    assert sec["key_file"] == str(cfg.parent / "keys" / "gcs.key")
    assert start["links"]["controller"]["security"]["signing_key"] == "none"
    rejected = next(e for e in ev if e["type"] == "serve_stop")["links"]["gcs"]["rejected"]
    assert rejected.get("unsigned", 0) >= 1 and rejected.get("not_allowed", 0) >= 1
    arms = [e for e in ev if e["type"] == "command_ack" and e.get("command") == "ARM"]
    assert len(arms) == 1, "only the signed ARM from system 255 reached the core"


def _gcs_local_port(sp) -> int:  # type: ignore[no-untyped-def]
    links = next(e for e in sp.events() if e["type"] == "serve_start")["links"]
    return int(links["gcs"]["local"][1])
