"""The frozen records that write their ``__init__`` out (``merlin.core.types``, module docstring).

Each such ``__init__`` has two halves: the compiled build stores the fields directly, the interpreted build
sets them through :func:`merlin.core.types.set_frozen_fields`. Both halves are checked against the class's
declared fields, from the source (names, order, defaults, which field each statement sets) and by
constructing every record in this process's build and in the interpreted one.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from merlin import _build

ROOT = Path(__file__).resolve().parents[2]
MODULES = ("merlin.core.types", "merlin.measurements", "merlin.core.geofence", "merlin.redundancy.lane_voter",
           "merlin.autopilot.fixedwing_control", "merlin.redundancy.lanes")
#: the records built on every closed-loop tick, whose constructors are written out: none may be dropped
#: from the list below without its constructor going back to the generated (interpreted) one
HOT_RECORDS = {
    "merlin.core.types": {"VehicleState", "Inputs", "Reason", "MonitorStatus", "ExperimentalInput"},
    "merlin.measurements": {"ImuSample", "GpsSample", "BaroSample", "MagSample"},
    "merlin.core.geofence": {"FenceResult"},
    # the autopilot lanes' exchange, every lane every exchange tick
    "merlin.redundancy.lane_voter": {"LaneMessage", "Received", "LaneVoterState", "LaneVote", "Selection"},
    # what every autopilot lane reads beside its sensors, every tick
    "merlin.redundancy.lanes": {"LaneContext"},
    # the fixed wing's loops, every control step
    "merlin.autopilot.fixedwing_control": {"SurfaceCommand", "FixedWingControlState", "ControlOutput", "_Energy"},
}


def _written_out(module: str) -> list[tuple[ast.ClassDef, ast.FunctionDef]]:
    path = ROOT / (module.replace(".", "/") + ".py")
    tree = ast.parse(path.read_text())
    out = []
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            inits = [f for f in node.body if isinstance(f, ast.FunctionDef) and f.name == "__init__"]
            if inits and any(isinstance(d, ast.Call) and getattr(d.func, "id", "") == "dataclass"
                             for d in node.decorator_list):
                out.append((node, inits[0]))
    return out


def _fields(cls_node: ast.ClassDef) -> list[tuple[str, ast.expr | None]]:
    return [(st.target.id, st.value) for st in cls_node.body
            if isinstance(st, ast.AnnAssign) and isinstance(st.target, ast.Name)]


def test_the_hot_records_write_their_constructor_out() -> None:
    for module, names in HOT_RECORDS.items():
        assert names <= {c.name for c, _ in _written_out(module)}, module


@pytest.mark.parametrize("module", MODULES)
def test_each_written_out_constructor_matches_its_fields(module: str) -> None:
    """Parameters = fields (names, order, defaults); the native half sets each field from its parameter,
    once, in order; the interpreted half passes the parameters in the fields' order."""
    mod = importlib.import_module(module)
    for cls_node, init in _written_out(module):
        fields = _fields(cls_node)
        names = [n for n, _ in fields]
        params = [a.arg for a in init.args.args[1:]]
        assert params == names, cls_node.name
        defaults = dict(zip(params[len(params) - len(init.args.defaults):], init.args.defaults, strict=True))
        cls = getattr(mod, cls_node.name)
        for name, value in fields:
            if value is None:
                assert name not in defaults, (cls_node.name, name)
                continue
            field = cls.__dataclass_fields__[name]
            got = eval(compile(ast.Expression(defaults[name]), module, "eval"), vars(mod))
            if field.default_factory is not dataclasses.MISSING:
                assert got == field.default_factory(), (cls_node.name, name)
            else:
                assert got == field.default and type(got) is type(field.default), (cls_node.name, name)
        (branch,) = init.body
        assert isinstance(branch, ast.If) and ast.unparse(branch.test) == "NATIVE", cls_node.name
        assert [ast.unparse(s) for s in branch.body] == [f"self.{n} = {n}" for n in names], cls_node.name
        (call,) = branch.orelse
        assert ast.unparse(call) == f"set_frozen_fields(self, ({', '.join(names)}{',' if len(names) == 1 else ''}))"


def _samples() -> dict[str, dict[str, Any]]:
    """Per record, a value for every field: of the field's type (the compiled build checks them), unlike
    its default and unlike the record's other fields of the same type, so a field set from the wrong
    parameter shows."""
    from merlin.autopilot.fixedwing_control import SurfaceCommand
    from merlin.core import types as t
    from merlin.redundancy.events import FaultKind, FaultReport
    from merlin.redundancy.lane_voter import LaneMessage

    v1, v2, v3 = (1.5, 2.5, 3.5), (4.5, 5.5, 6.5), (7.5, 8.5, 9.5)
    reason = t.Reason(t.ReasonCode.GEOFENCE, "fence")
    msg = LaneMessage(2, 3.25, (True, False), 1, (True, False, True))
    fault = FaultReport(1.0, next(iter(FaultKind)), "gps")
    return {
        "Reason": dict(code=t.ReasonCode.GEOFENCE, monitor="m", parameter="p", value=1.5, limit=2.5,
                       duration_s=3.5, text="x"),
        "VehicleState": dict(pos_ned_m=v1, vel_ned_mps=v2, att_rpy_rad=v3, rates_frd_radps=(1.0, 1.0, 1.0),
                             accel_frd_mps2=(2.0, 2.0, 2.0), airspeed_mps=1.25, pos_sigma_h_m=2.25,
                             pos_sigma_v_m=3.25, nav_mode=t.NavMode.INERTIAL, nav_inertial_s=4.25, armed=True,
                             landed=False, battery_frac=0.25, alpha_rad=0.125),
        "ExperimentalInput": dict(heartbeat_t_s=1.5, setpoint=t.Setpoint(t.SetpointKind.VELOCITY, v1),
                                  setpoint_t_s=2.5, requests=(t.AuthorityRequest(t.RequestKind.ACK, 3),)),
        "Inputs": dict(state=t.VehicleState(v1), experimental=t.ExperimentalInput(1.5),
                       operator=t.OperatorInput(2.5), gcs_link_t_s=3.5,
                       gcs_commands=(t.GcsCommand(t.GcsCommandKind.ARM),), redundancy=t.RedundancyReport(2)),
        "MonitorStatus": dict(name="fence", tripped=True, reason=reason, detail=(("margin", 1.5),)),
        "ImuSample": dict(t_s=1.5, gyro_frd_radps=v1, accel_frd_mps2=v2, lane=2),
        "GpsSample": dict(t_s=1.5, pos_ned_m=v1, vel_ned_mps=v2, fix_type=3, satellites=9, eph_m=2.25,
                          epv_m=3.25, lane=1),
        "BaroSample": dict(t_s=1.5, alt_m=2.5, lane=2),
        "MagSample": dict(t_s=1.5, field_frd_gauss=v1, lane=1),
        "FenceResult": dict(tripped=True, kind="ceiling", stopping_distance_m=1.5, clearance_m=2.5),
        "LaneMessage": dict(sender=2, t_sent_s=1.5, flags=(True, False), vote=1, hears=(False, True, True)),
        "Received": dict(t_rx_s=1.5, msg=msg),
        "LaneVoterState": dict(since=((1.5, None),), latched_until=((2.5,),), silent=(True, False, False),
                               vote=2, self_isolated=True, gated=False),
        "LaneVote": dict(t_s=1.5, lane=1, vote=2, counters=(1, 2, 3), priorities=(3, 2, 1),
                         silent=(False, True, False), self_isolated=True, gated=False, message=msg,
                         events=(fault,)),
        "Selection": dict(t_s=1.5, lane=2, votes=(1, None, 2), events=(fault,)),
        "LaneContext": dict(battery_ok=False, no_failsafe=False, data_link_ok=False),
        "SurfaceCommand": dict(aileron=0.125, elevator=0.25, rudder=0.375, throttle=0.5),
        "FixedWingControlState": dict(throttle_integ=1.5, pitch_tecs_integ_rad=2.5, roll_sp_rad=3.5,
                                      pitch_sp_rad=4.5, aileron_integ=5.5, elevator_integ=6.5, rudder_integ=7.5,
                                      speed_rate_mps2=8.5, throttle=0.75, initialized=True, recovering=True,
                                      pulling_out=True, handover=v1),
        "ControlOutput": dict(surfaces=SurfaceCommand(0.5), roll_sp_rad=1.5, pitch_sp_rad=2.5,
                              pitch_target_rad=3.5, ste_rate_error=4.5, seb_rate_error=5.5, height_weight=0.25,
                              underspeed=True, recovering=True),
        "_Energy": dict(ste_d=1.5, ste=2.5, seb_d=3.5, seb=4.5, w_h=0.25, underspeed=True),
    }


def _construct_all() -> dict[str, Any]:
    """Every written-out record built from its sample values, by keyword and by position: which fields
    came out wrong, whether assignment is refused, whether ``replace`` copies, and each module's build."""
    report: dict[str, Any] = {"native": {}, "wrong": [], "not_frozen": [], "replace_wrong": [], "missing": []}
    samples = _samples()
    for module in MODULES:
        mod = importlib.import_module(module)
        report["native"][module] = bool(mod.NATIVE)
        for cls_node, _ in _written_out(module):
            cls = getattr(mod, cls_node.name)
            names = [f.name for f in dataclasses.fields(cls)]
            values = samples.get(cls_node.name)
            if values is None or list(values) != names:
                report["missing"].append(cls_node.name)
                continue
            for obj in (cls(**values), cls(*values.values())):
                report["wrong"] += [f"{cls_node.name}.{n}" for n in names if getattr(obj, n) != values[n]]
            obj = cls(**values)
            try:
                setattr(obj, names[0], values[names[0]])
                report["not_frozen"].append(cls_node.name)
            except dataclasses.FrozenInstanceError:
                pass
            again = dataclasses.replace(obj)  # every field passed back through __init__ by keyword
            if any(getattr(again, n) != values[n] for n in names):
                report["replace_wrong"].append(cls_node.name)
    return report


def _check(report: dict[str, Any]) -> None:
    assert report["missing"] == [] and report["wrong"] == [] and report["not_frozen"] == [], report
    assert report["replace_wrong"] == [], report


def test_records_built_in_this_build_hold_what_was_passed() -> None:
    report = _construct_all()
    _check(report)
    # the fast half is the one taken wherever the module is an extension module
    for module, native in report["native"].items():
        assert native == _build.compiled_modules()[module], module


def test_records_built_in_the_interpreted_build_hold_what_was_passed() -> None:
    code = ("import json, sys; sys.path.insert(0, '.'); from tests.core import test_frozen_records as t; "
            "print(json.dumps(t._construct_all()))")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True,
                         env={**os.environ, "MERLIN_USE_SOURCES": "1"})
    report = json.loads(res.stdout.strip().splitlines()[-1])
    _check(report)
    assert not any(report["native"].values()), report["native"]
