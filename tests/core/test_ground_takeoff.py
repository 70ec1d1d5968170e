"""A controller granted on the ground flies its own take-off, as PX4's offboard flows let it (MAVSDK's
offboard_attitude example arms, sends an attitude setpoint and starts OFFBOARD on the ground): the altitude
floors (the envelope's altitude minimum, the fence floor) judge it once the vehicle is above them, or
``handover.ground_takeoff_s`` after it left the ground; every other limit from the first tick. The serve-level
flow is pinned by tests/serve/test_px4_examples_grpc.py::test_offboard_attitude."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from merlin.config.models import MerlinConfig
from merlin.core.types import (
    Authority,
    Decision,
    EventKind,
    GcsCommandKind,
    ReasonCode,
    Setpoint,
    SetpointKind,
    VehicleState,
)
from tests.core.harness import Harness, events_of

ATTITUDE = Setpoint(SetpointKind.ATTITUDE, att_rpy_rad=(0.0, 0.0, 0.0), thrust=0.0)
DEFAULT = MerlinConfig()
LIMIT = DEFAULT.envelope.resolve(DEFAULT.envelope.active_stage)["altitude_m"]  # the conservative stage: 3 m
TAKEOFF_S = DEFAULT.handover.ground_takeoff_s


def _at(h: float, vd: float = 0.0, landed: bool = False, vn: float = 0.0) -> VehicleState:
    return VehicleState(pos_ned_m=(0.0, 0.0, -h), vel_ned_mps=(vn, 0.0, vd), armed=True, landed=landed)


def _granted_on_the_ground(cfg: MerlinConfig = DEFAULT) -> Harness:
    h = Harness(cfg=cfg, setpoint=ATTITUDE)
    h.state = _at(0.0, landed=True)
    assert h.command(GcsCommandKind.ARM).armed
    h.run(1.5)  # the controller's heartbeat unbroken for the handover's 1 s
    assert h.grant().authority is Authority.EXPERIMENTAL
    return h


def _revoked(d: Decision) -> list:
    return events_of(d, EventKind.REVOKED)


def test_a_grant_on_the_ground_is_judged_without_the_floor_and_the_take_off_climbs_through_it() -> None:
    h = _granted_on_the_ground()
    h.run(1.0)  # on the ground, motors at the controller's thrust: below the floor, never revoked for it
    for k in range(1, 400):  # 0 to 10 m at 2 m/s
        d = h.tick(state=_at(0.01 * k, vd=-2.0))
        assert not _revoked(d), [e.to_dict() for e in d.events]
        assert d.authority is Authority.EXPERIMENTAL
    assert h.core.state.ground_takeoff_since_s is None  # above the floor: the take-off is over


def test_once_above_the_floor_a_descent_below_it_is_revoked() -> None:
    h = _granted_on_the_ground()
    for k in range(1, 500):
        h.tick(state=_at(0.01 * k, vd=-2.0))
    revoked = []
    for k in range(800):  # down from 5 m to 1 m at 2 m/s, through the floor
        revoked += _revoked(h.tick(state=_at(5.0 - 0.005 * k, vd=2.0)))
    assert [(r.reason.code, r.reason.parameter) for r in revoked] == [(ReasonCode.ENVELOPE, "altitude_m")]


def test_a_controller_that_stays_below_the_floor_is_revoked_after_ground_takeoff_s() -> None:
    h = _granted_on_the_ground()
    h.tick(state=_at(1.0, vd=-0.1))  # left the ground
    t_left = h.t
    revoked = []
    while not revoked and h.t < t_left + TAKEOFF_S + 2.0:
        revoked = _revoked(h.tick(state=_at(1.0)))
    assert revoked and revoked[0].reason.parameter == "altitude_m", revoked
    # the floor applied from ground_takeoff_s after the vehicle left the ground, and tripped after its duration
    assert h.t - t_left <= TAKEOFF_S + LIMIT.duration_s + 2 * h.dt
    assert h.t - t_left >= TAKEOFF_S + LIMIT.duration_s - h.dt


def test_every_other_limit_judges_the_take_off_from_the_first_tick() -> None:
    h = _granted_on_the_ground()
    revoked = []
    for _ in range(400):  # 1.5 m up, climbing at 5 m/s: beyond the conservative stage's 3 m/s
        revoked += _revoked(h.tick(state=_at(1.5, vd=-5.0)))
    assert revoked and revoked[0].reason.parameter == "vel_d_mps", revoked


def test_a_request_in_the_air_below_the_floor_is_still_denied() -> None:
    """Only a take-off from the ground defers the floor: a request from a vehicle Merlin flew to 1 m is judged
    on the envelope as it stands."""
    h = Harness(setpoint=ATTITUDE)
    h.state = _at(0.0, landed=True)
    assert h.command(GcsCommandKind.ARM).armed
    h.command(GcsCommandKind.TAKEOFF, 10.0)
    h.run(1.5, state=_at(1.0, vd=-1.0))
    denied = events_of(h.request(), EventKind.DENIED)
    assert denied and denied[0].reason.parameter == "altitude_m", denied


def test_the_fence_floor_is_deferred_for_the_take_off_and_applies_once_clear() -> None:
    cfg = MerlinConfig.model_validate({"geofence": {"altitude_floor_m": 4.0}})
    h = _granted_on_the_ground(cfg)  # not refused: "not yet clear of the fence floor" is for the air
    tripped = False
    for k in range(1, 1000):  # up to 25 m, well clear of the floor plus its margin
        d = h.tick(state=_at(0.025 * k, vd=-2.0))
        assert not _revoked(d), [e.to_dict() for e in d.events]
    for k in range(1, 2000):
        d = h.tick(state=_at(25.0 - 0.0125 * k, vd=1.5))
        tripped = tripped or any(r.reason.code is ReasonCode.GEOFENCE for r in _revoked(d))
        if tripped:
            break
    assert tripped


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(0.1, 2.9), min_size=1, max_size=30))
def test_the_floor_deferral_never_outlives_ground_takeoff_s(heights: list[float]) -> None:
    """Safety invariant: however a controller granted on the ground moves below the floor, the floor judges it
    from ground_takeoff_s after it left the ground, and revokes it within the limit's duration after that."""
    h = _granted_on_the_ground()
    h.tick(state=_at(heights[0]))
    t_left = h.t
    k = 0
    revoked = []
    while not revoked and h.t < t_left + TAKEOFF_S + LIMIT.duration_s + 0.1:
        revoked = _revoked(h.tick(state=_at(heights[k % len(heights)])))
        k += 1
    assert revoked and revoked[0].reason.parameter == "altitude_m"
    assert h.t - t_left <= TAKEOFF_S + LIMIT.duration_s + 2 * h.dt
