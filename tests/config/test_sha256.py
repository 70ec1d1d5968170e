"""The canonical SHA-256 names the effective configuration, not the file's layout."""

from __future__ import annotations

import random

import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.cli import main
from merlin.config.loader import config_sha256, load_config, load_config_text
from tests.config.paths import EXAMPLES

SHORT = """\
name: sha-test
envelope:
  active_stage: trial
  stages:
    trial:
      extends: conservative
      roll_deg: {min: -40, max: 40, duration_s: 0.5}
geofence:
  margin_m: 8
"""

# The same configuration: comments, other key order, flow/block style, ints written as floats, and
# defaults written out (merlin_config_version, enabled: true, the built-in `conservative` parent, a
# watchdog, an arbiter row and a whole section at their defaults).
SAME_LONGER = """\
# The same flight as SHORT, written differently.
geofence:
  margin_m: 8.0        # metres
  sigma_k: 2.0         # default
  mode: velocity_projection
watchdogs:
  rc_link:
    timeout_s: 1.0
arbiter:
  rules:
    geofence: {trusted: rtl, operator: rtl, experimental: rtl, clear: on_request}
battery: {critical_frac: 0.1, low_frac: 0.25}
merlin_config_version: 1
envelope:
  stages:
    trial:
      roll_deg:
        enabled: true
        duration_s: 0.5
        max: 40.0
        min: -40.0
      extends: conservative
      description: ""
    conservative:   # the built-in stage, written out exactly
      description: "first flights of an unproven controller: tight bounds, short durations"
      airspeed_mps:     {min: 0.0,    max: 20.0,  duration_s: 0.5, enabled: false, budget: {outside_s: 2.0, window_s: 20.0}}
      altitude_m:       {min: 3.0,    max: 100.0, duration_s: 0.5, budget: {outside_s: 2.0, window_s: 20.0}}
      vel_n_mps:        {min: -8.0,   max: 8.0,   duration_s: 0.5, budget: {outside_s: 2.0, window_s: 20.0}}
      vel_e_mps:        {min: -8.0,   max: 8.0,   duration_s: 0.5, budget: {outside_s: 2.0, window_s: 20.0}}
      vel_d_mps:        {min: -3.0,   max: 2.0,   duration_s: 0.5, budget: {outside_s: 2.0, window_s: 20.0}}
      roll_deg:         {min: -30.0,  max: 30.0,  duration_s: 0.0}
      pitch_deg:        {min: -30.0,  max: 30.0,  duration_s: 0.0}
      yaw_deg:          {min: -180.0, max: 180.0, duration_s: 0.0, enabled: false}
      roll_rate_degps:  {min: -150.0, max: 150.0, duration_s: 0.2, budget: {outside_s: 2.0, window_s: 20.0}}
      pitch_rate_degps: {min: -150.0, max: 150.0, duration_s: 0.2, budget: {outside_s: 2.0, window_s: 20.0}}
      yaw_rate_degps:   {min: -90.0,  max: 90.0,  duration_s: 0.5, budget: {outside_s: 2.0, window_s: 20.0}}
      accel_x_mps2:     {min: -15.0,  max: 15.0,  duration_s: 0.2, budget: {outside_s: 2.0, window_s: 20.0}}
      accel_y_mps2:     {min: -15.0,  max: 15.0,  duration_s: 0.2, budget: {outside_s: 2.0, window_s: 20.0}}
      accel_z_mps2:     {min: -25.0,  max: 5.0,   duration_s: 0.2, budget: {outside_s: 2.0, window_s: 20.0}}
      alpha_deg:        {min: -8.0,   max: 15.0,  duration_s: 0.2, enabled: false, budget: {outside_s: 2.0, window_s: 20.0}}
  active_stage: trial
name: sha-test
"""


def _sha(text: str) -> str:
    return config_sha256(load_config_text(text))


def test_sha_ignores_comments_key_order_and_explicit_defaults() -> None:
    assert _sha(SHORT) == _sha(SAME_LONGER)


def test_sha_changes_when_a_limit_changes() -> None:
    base = _sha(SHORT)
    assert _sha(SHORT.replace("max: 40", "max: 41")) != base
    assert _sha(SHORT.replace("duration_s: 0.5", "duration_s: 0.6")) != base
    assert _sha(SHORT.replace("margin_m: 8", "margin_m: 8.001")) != base
    assert _sha(SHORT.replace("active_stage: trial", "active_stage: conservative")) != base


def test_check_config_prints_the_same_sha_for_both_files(tmp_path, capsys) -> None:
    shas = []
    for i, text in enumerate((SHORT, SAME_LONGER)):
        path = tmp_path / f"f{i}.yaml"
        path.write_text(text, encoding="utf-8")
        assert main(["check-config", str(path)]) == 0
        line = next(x for x in capsys.readouterr().out.splitlines() if x.strip().startswith("sha256:"))
        shas.append(line.split()[1])
    assert shas[0] == shas[1] == _sha(SHORT)


def _shuffled(node: object, rng: random.Random) -> object:
    if isinstance(node, dict):
        items = list(node.items())
        rng.shuffle(items)
        return {k: _shuffled(v, rng) for k, v in items}
    if isinstance(node, list):
        return [_shuffled(v, rng) for v in node]  # list order is meaning (vertices): kept
    return node


_DEFAULT_TEXT = (EXAMPLES / "default.yaml").read_text(encoding="utf-8")
_DEFAULT_SHA = config_sha256(load_config(EXAMPLES / "default.yaml"))


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), flow=st.booleans())
def test_sha_is_independent_of_key_order_and_style(seed: int, flow: bool) -> None:
    data = _shuffled(yaml.safe_load(_DEFAULT_TEXT), random.Random(seed))
    text = yaml.safe_dump(data, sort_keys=False, default_flow_style=flow)
    assert _sha(text) == _DEFAULT_SHA
