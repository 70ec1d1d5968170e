"""The fusion EKF's settings come from the configuration file: ``nav.filter`` (pydantic, bounded and
documented) mirrors :class:`merlin.nav.config.NavConfig` field for field, with the same defaults."""

from __future__ import annotations

import dataclasses
import math

import pytest

from merlin.config.loader import ConfigError, load_config_text
from merlin.config.models import MerlinConfig, NavFilterConfig
from merlin.nav.config import FROM_ELSEWHERE, NavConfig, nav_config_from_model
from sims.vision_loop import nav_filter_config


def test_nav_filter_fields_match_the_dataclass_one_to_one():
    own = {f.name for f in dataclasses.fields(NavConfig)}
    model = set(NavFilterConfig.model_fields) - {"mag_declination_deg"}
    assert own - set(FROM_ELSEWHERE) == model
    assert set(FROM_ELSEWHERE) <= own


def test_nav_filter_defaults_equal_the_dataclass_defaults():
    built = nav_config_from_model(NavFilterConfig(), inertial_time_limit_s=30.0, home_declination_rad=0.0)
    assert built == NavConfig()
    for f in dataclasses.fields(NavConfig):
        if f.name not in FROM_ELSEWHERE:
            assert type(getattr(built, f.name)) is type(f.default), f.name


def test_every_nav_filter_field_is_described():
    for name, info in NavFilterConfig.model_fields.items():
        assert info.description, name


def test_a_scenario_config_reaches_the_filter():
    cfg = MerlinConfig.model_validate(
        {"nav": {"inertial_time_limit_s": 12.0, "filter": {"gps_readmit_s": 4.5, "gps_min_satellites": 8}}}
    )
    nc = nav_filter_config(cfg)
    assert nc.gps_readmit_s == 4.5
    assert nc.gps_min_satellites == 8
    assert nc.inertial_time_limit_s == 12.0
    # the declination comes from the field model at home unless it is set
    assert nc.mag_declination_rad != 0.0
    cfg2 = MerlinConfig.model_validate({"nav": {"filter": {"mag_declination_deg": 10.0}}})
    assert nav_filter_config(cfg2).mag_declination_rad == pytest.approx(math.radians(10.0))


@pytest.mark.parametrize(
    ("field", "value", "allowed"),
    [
        ("gps_readmit_s", 1000.0, "less than or equal to 600"),
        ("gps_cusum_allowance", 0.9, "greater than 1"),
        ("gps_min_satellites", 2, "greater than or equal to 4"),
        ("vo_min_inlier_ratio", 1.5, "less than or equal to 1"),
    ],
)
def test_an_out_of_range_value_names_the_field_the_value_and_the_range(field, value, allowed):
    text = f"nav:\n  filter:\n    {field}: {value}\n"
    with pytest.raises(ConfigError) as err:
        load_config_text(text, source="flight.yaml")
    msg = str(err.value)
    assert "flight.yaml" in msg
    assert f"nav.filter.{field}" in msg
    assert allowed in msg
    assert str(value) in msg


def test_inconsistent_vo_limits_are_refused():
    with pytest.raises(
        ConfigError, match=r"vo_good_features \(80\) must not be below vo_min_features \(100\)"
    ):
        load_config_text("nav:\n  filter:\n    vo_min_features: 100\n", source="flight.yaml")


def test_an_unknown_nav_filter_key_is_refused():
    with pytest.raises(ConfigError, match=r"nav\.filter\.gps_readmit: unknown key"):
        load_config_text("nav:\n  filter:\n    gps_readmit: 5\n", source="flight.yaml")


def test_mode_behaviour_is_read_from_the_core_rule_table():
    """merlin.nav.modes keeps no rule table of its own: what a navigation mode leads to is the configured
    arbiter.rules row of each core monitor the mode trips."""
    from merlin.config.models import MONITORS
    from merlin.core.types import NavMode
    from merlin.nav.modes import MODE_MONITORS, configured_actions

    assert {m for ms in MODE_MONITORS.values() for m in ms} <= set(MONITORS)
    rules = MerlinConfig().arbiter.rules
    assert configured_actions(NavMode.GPS, rules) == {}
    assert configured_actions(NavMode.VO, rules) == {"nav_gps_lost": "rtl"}
    assert configured_actions(NavMode.INERTIAL, rules) == {
        "nav_gps_lost": "rtl",
        "nav_inertial_timeout": "land",
    }
    assert configured_actions(NavMode.LOST, rules) == {"nav_lost": "land"}
    assert configured_actions(NavMode.VO, rules, "operator") == {"nav_gps_lost": "warn"}
    custom = MerlinConfig.model_validate(
        {
            "arbiter": {
                "rules": {"nav_gps_lost": {"experimental": "hold", "operator": "warn", "trusted": "hold"}}
            }
        }
    ).arbiter.rules
    assert configured_actions(NavMode.VO, custom) == {"nav_gps_lost": "hold"}
