"""log.parquet describes itself: a unit for every quantity (one unit per quantity: angles in degrees only),
enum labels in the schema and as dictionary-encoded names, booleans, latitude/longitude beside NED; the
run's log (and so its decisions_digest) is not changed by writing it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from merlin.core.types import Authority
from merlin.geodesy import LocalFrame
from sims.report import write_log
from sims.runner import run_scenario
from sims.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> tuple[object, object, dict[str, bytes]]:
    sc, cfg = load_scenario(ROOT / "examples" / "scenarios" / "figure5_instant.yaml")
    r = run_scenario(sc, cfg)
    before = {k: np.ascontiguousarray(v).tobytes() for k, v in r.log.items()}
    path = write_log(r, tmp_path_factory.mktemp("pq"))
    return r, pq.read_table(path), before


def test_units_labels_and_one_unit_per_quantity(written: tuple) -> None:
    r, table, before = written
    assert {k: np.ascontiguousarray(v).tobytes() for k, v in r.log.items()} == before
    schema = table.schema
    units = {}
    for f in schema:
        meta = f.metadata or {}
        if f.type == "bool" or b"labels" in meta or f.name.endswith("_name"):
            continue
        assert b"unit" in meta, f"{f.name} has no unit"
        units[f.name] = meta[b"unit"].decode()
    assert not [n for n, u in units.items() if "rad" in u], "radians beside degrees"
    angles = [n for n, u in units.items() if u.startswith("deg") and "WGS84" not in u and "/s" not in u]
    assert all(n.endswith("_deg") for n in angles) and "truth_roll_deg" in angles and "env_roll_deg" in angles
    assert not {"truth_roll", "cmd_roll", "sp_roll"} & set(schema.names)
    assert np.allclose(table["truth_roll_deg"].to_numpy(), np.degrees(r.log["truth_roll"]))
    labels = json.loads(schema.field("authority").metadata[b"labels"])
    assert labels["2"] == "EXPERIMENTAL"
    names = table["authority_name"].to_pylist()
    codes = table["authority"].to_numpy()
    assert all(Authority(int(c)).name == n for c, n in zip(codes, names, strict=True))
    assert "EXPERIMENTAL" in names and str(table.schema.field("authority_name").type).startswith("dictionary")
    assert table.schema.field("armed").type == "bool" and table.schema.field("mon_envelope").type == "bool"
    home = r.config.home
    lat, lon = LocalFrame(home.lat_deg, home.lon_deg).latlon_from_ne(r.log["truth_n"], r.log["truth_e"])
    assert np.allclose(table["truth_lat_deg"].to_numpy(), lat) and np.allclose(table["truth_lon_deg"].to_numpy(), lon)
    assert np.allclose(table["est_alt_m"].to_numpy(), home.alt_amsl_m - r.log["est_d"])
    meta = schema.metadata
    assert meta[b"decisions_digest"].decode() == r.decisions_digest and b"WGS84" in meta[b"frame"]
