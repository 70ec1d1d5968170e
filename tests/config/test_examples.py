"""The example configurations load, build and say what their comments claim."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import pytest
import shapely
import yaml

from merlin.commands.check_config import load_and_build
from merlin.config.loader import config_sha256, load_config
from merlin.config.models import ENVELOPE_PARAMETERS, MerlinConfig
from merlin.config.summary import envelope_table, fence_summary
from merlin.core.types import Authority, EventKind
from tests.config.paths import EXAMPLE_FILES, EXAMPLES
from tests.core.harness import DT, HOVER_10M, Harness, events_of

EXPECTED = {"default.yaml", "figure5_instant.yaml", "figure5_delayed.yaml", "expansion_campaign.yaml"}


def test_the_four_examples_exist() -> None:
    assert {p.name for p in EXAMPLE_FILES} >= EXPECTED


@pytest.mark.parametrize("path", EXAMPLE_FILES, ids=lambda p: p.name)
def test_every_example_loads_and_builds(path) -> None:
    checked = load_and_build(path)
    assert checked.core.config_sha256 == config_sha256(load_config(path))
    assert len(checked.core.config_sha256) == 64
    assert checked.core.envelope  # at least one enabled limit
    assert checked.core.fence is not None


# ------------------------------------------------------------------------------------------ default


def _default_yaml() -> dict:
    return yaml.safe_load((EXAMPLES / "default.yaml").read_text(encoding="utf-8"))


def test_default_yaml_spells_out_every_key_of_every_section() -> None:
    data = _default_yaml()
    assert set(data) == set(MerlinConfig.model_fields)
    cfg = MerlinConfig()
    for section, value in data.items():
        model = getattr(cfg, section)
        if hasattr(type(model), "model_fields"):
            missing = set(type(model).model_fields) - set(value)
            assert not missing, f"default.yaml section {section!r} leaves out {sorted(missing)}"


@pytest.mark.parametrize(
    "section",
    ["vehicle", "envelope", "watchdogs", "arbiter", "handover", "operator", "trusted", "nav", "battery"],
)
def test_default_yaml_values_are_the_model_defaults(section: str) -> None:
    # Only the site (name, home, geofence zones) is an example; everything else is the models' default.
    assert getattr(load_config(EXAMPLES / "default.yaml"), section) == getattr(MerlinConfig(), section)


def test_default_yaml_fence_is_a_realistic_non_convex_range() -> None:
    checked = load_and_build(EXAMPLES / "default.yaml")
    g = checked.cfg.geofence
    assert g.altitude_ceiling_m == 120.0 and g.altitude_floor_m is None
    assert len(g.inclusion_polygons) == 1 and g.inclusion_polygons[0].vertices_deg is not None
    assert len(g.exclusion_polygons) == 1 and len(g.exclusion_circles) == 1
    assert g.exclusion_circles[0].center_deg is not None
    fence = checked.core.fence
    assert fence is not None
    shell = fence.inclusion_polygons[0].shell_ne_m
    assert 10 <= len(shell) <= 12
    poly = shapely.Polygon(shell)
    assert poly.is_valid and poly.convex_hull.area > poly.area * 1.02  # non-convex
    n0, e0, n1, e1 = poly.bounds
    assert n1 - n0 == pytest.approx(400.0, abs=2.0)  # north-south extent, metres
    assert e1 - e0 == pytest.approx(600.0, abs=2.0)  # east-west extent
    assert poly.contains(shapely.Point(0.0, 0.0))  # home is inside the range
    zones = fence_summary(checked.cfg, fence).zones.records()
    assert [z["kind"] for z in zones] == ["inclusion", "exclusion", "exclusion"]
    assert zones[0]["vertices"] == len(shell)
    assert zones[0]["area_m2"] == pytest.approx(poly.area, abs=0.1)
    # the comments give each vertex in metres about home: they agree with the projection to 1 m
    text = (EXAMPLES / "default.yaml").read_text(encoding="utf-8")
    first = text.split("vertices_deg:")[1].splitlines()[1]
    n_c, e_c = (float(x.split()[0]) for x in first.split("#")[1].split(","))
    assert (n_c, e_c) == pytest.approx(shell[0], abs=1.0)


# ------------------------------------------------------------------------------------------ figure 5


def _fig5(kind: str) -> MerlinConfig:
    return load_config(EXAMPLES / f"figure5_{kind}.yaml")


def test_figure5_presets_differ_only_in_roll_duration() -> None:
    inst, dela = _fig5("instant"), _fig5("delayed")
    a, b = inst.envelope.effective(), dela.envelope.effective()
    assert a["roll_deg"].duration_s == 0.0 and b["roll_deg"].duration_s == 1.0
    assert (a["roll_deg"].min, a["roll_deg"].max) == (b["roll_deg"].min, b["roll_deg"].max) == (-30.0, 30.0)
    assert {p for p in ENVELOPE_PARAMETERS if a[p] != b[p]} == {"roll_deg"}
    same = ("home", "vehicle", "geofence", "watchdogs", "arbiter", "handover", "operator", "trusted", "nav")
    for section in same:
        assert getattr(inst, section) == getattr(dela, section)
    assert config_sha256(inst) != config_sha256(dela)


def _roll(deg: float):
    return replace(HOVER_10M, att_rpy_rad=(math.radians(deg), 0.0, 0.0))


def test_figure5_instant_revokes_on_the_tick_of_violation() -> None:  # paper Figure 5, Point A
    h = Harness(cfg=_fig5("instant"))
    h.airborne()
    h.grant()
    d = h.tick(state=_roll(31.0))
    assert d.authority is Authority.TRUSTED
    assert events_of(d, EventKind.REVOKED)


def test_figure5_delayed_tolerates_brief_violation_and_revokes_after_one_second() -> None:
    h = Harness(cfg=_fig5("delayed"))
    h.airborne()
    h.grant()
    ticks_per_s = round(1.0 / DT)
    h.state = _roll(35.0)
    for _ in range(ticks_per_s - 1):  # Point B: a violation shorter than 1 s is tolerated
        assert h.tick().authority is Authority.EXPERIMENTAL
    assert h.tick(state=_roll(20.0)).authority is Authority.EXPERIMENTAL  # back inside: timer resets
    h.state = _roll(35.0)
    k0 = h.k
    while h.tick().authority is Authority.EXPERIMENTAL:
        assert h.k - k0 <= ticks_per_s + 1
    assert h.k - 1 - k0 == ticks_per_s  # Point C: revoked exactly 1 s after the violation began


# ----------------------------------------------------------------------------------- expansion campaign


def test_expansion_campaign_stages_extend_in_a_chain_and_widen() -> None:
    cfg = load_config(EXAMPLES / "expansion_campaign.yaml")
    chain = ["conservative", "intermediate", "expanded"]
    assert cfg.envelope.stages["intermediate"].extends == "conservative"
    assert cfg.envelope.stages["expanded"].extends == "intermediate"
    resolved = [cfg.envelope.resolve(s) for s in chain]
    for narrow, wide in itertools.pairwise(resolved):
        for p in ENVELOPE_PARAMETERS:
            assert wide[p].min <= narrow[p].min and wide[p].max >= narrow[p].max, p
            assert wide[p].duration_s >= narrow[p].duration_s, p
    # inherited through two levels: expanded gives no yaw_deg, intermediate none either
    assert resolved[2]["yaw_deg"] == cfg.envelope.stages["conservative"].yaw_deg
    table = envelope_table(cfg, "expanded").records()
    set_in = {r["parameter"]: r["set_in"] for r in table}
    assert set_in["yaw_deg"] == "conservative" and set_in["roll_deg"] == "expanded"
    assert envelope_table(cfg, "intermediate").records()[5]["set_in"] == "intermediate"  # roll_deg
