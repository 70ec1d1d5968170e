"""A small driver for the trusted core in tests: holds the inputs, ticks at a fixed period, and knows the
standard moves (arm, take off, hand over to the experimental controller)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from merlin.config.loader import config_sha256
from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.config import CoreConfig
from merlin.core.step import TrustedCore
from merlin.core.types import (
    Authority,
    AuthorityRequest,
    Decision,
    EventKind,
    ExperimentalInput,
    GcsCommand,
    GcsCommandKind,
    Inputs,
    OperatorInput,
    RequestKind,
    Setpoint,
    SetpointKind,
    VehicleState,
)

DT = 0.0025  # 400 Hz

_CORE_CFG_CACHE: dict[str, CoreConfig] = {}

HOVER_10M = VehicleState(pos_ned_m=(0.0, 0.0, -10.0), armed=True, landed=False)


@dataclass
class Harness:
    cfg: MerlinConfig = field(default_factory=MerlinConfig)
    dt: float = DT
    k: int = 0
    state: VehicleState = field(default_factory=lambda: VehicleState(landed=True))
    heartbeat: bool = True  # the controller sends a heartbeat every tick
    setpoint: Setpoint | None = field(default_factory=lambda: Setpoint(SetpointKind.VELOCITY))
    setpoint_fresh: bool = True
    gcs_alive: bool = True
    rc_alive: bool | None = None  # None: no RC ever connected
    operator: OperatorInput = field(default_factory=OperatorInput)
    last_hb_t: float | None = None
    last_sp_t: float | None = None
    last_gcs_t: float | None = None
    last_rc_t: float | None = None
    history: list[Decision] = field(default_factory=list)

    def __post_init__(self) -> None:
        key = config_sha256(self.cfg)
        core_cfg = _CORE_CFG_CACHE.get(key)
        if core_cfg is None:  # building the fence (projection, prepared geometry) is the slow part
            core_cfg = _CORE_CFG_CACHE.setdefault(key, build_core_config(self.cfg))
        self.core = TrustedCore(core_cfg)

    @property
    def t(self) -> float:
        return self.k * self.dt

    def tick(
        self,
        requests: tuple[AuthorityRequest, ...] = (),
        commands: tuple[GcsCommand, ...] = (),
        state: VehicleState | None = None,
    ) -> Decision:
        t = self.t
        if state is not None:
            self.state = state
        if self.heartbeat:
            self.last_hb_t = t
        if self.setpoint_fresh and self.setpoint is not None:
            self.last_sp_t = t
        if self.gcs_alive:
            self.last_gcs_t = t
        if self.rc_alive:
            self.last_rc_t = t
        op = replace(self.operator, link_t_s=self.last_rc_t)
        inputs = Inputs(
            state=self.state,
            experimental=ExperimentalInput(
                heartbeat_t_s=self.last_hb_t,
                setpoint=self.setpoint,
                setpoint_t_s=self.last_sp_t,
                requests=requests,
            ),
            operator=op,
            gcs_link_t_s=self.last_gcs_t,
            gcs_commands=commands,
        )
        d = self.core.step(t, inputs)
        self.history.append(d)
        self.k += 1
        return d

    def run(self, seconds: float, **kw: object) -> Decision:
        n = round(seconds / self.dt)
        d = self.tick(**kw)  # type: ignore[arg-type]
        for _ in range(n - 1):
            d = self.tick()
        return d

    def command(self, kind: GcsCommandKind, param: float = 0.0, force: bool = False) -> Decision:
        return self.tick(commands=(GcsCommand(kind, param=param, force=force),))

    def airborne(self, at: VehicleState = HOVER_10M) -> Decision:
        """Arm on the ground, take off, and place the vehicle hovering at 10 m under TRUSTED HOLD."""
        self.state = replace(at, pos_ned_m=(at.pos_ned_m[0], at.pos_ned_m[1], 0.0), landed=True)
        d = self.command(GcsCommandKind.ARM)
        assert d.armed, [e.to_dict() for e in d.events]
        self.command(GcsCommandKind.TAKEOFF, 10.0)
        self.state = at
        return self.run(1.5)

    def request(self, shadow: bool = False) -> Decision:
        kind = RequestKind.REQUEST_SHADOW if shadow else RequestKind.REQUEST
        return self.tick(requests=(AuthorityRequest(kind),))

    def ack(self, seq: int) -> Decision:
        return self.tick(requests=(AuthorityRequest(RequestKind.ACK, seq=seq),))

    def grant(self, shadow: bool = False) -> Decision:
        """The full positive exchange: REQUEST -> GRANT -> ACK -> switch on the next tick."""
        d = self.request(shadow)
        granted = [e for e in d.events if e.kind is EventKind.GRANTED]
        assert granted, [e.to_dict() for e in d.events]
        self.ack(granted[0].seq)
        d = self.tick()
        want = Authority.SHADOW if shadow else Authority.EXPERIMENTAL
        assert d.authority is want, [e.to_dict() for e in d.events]
        return d


def events_of(d: Decision, kind: EventKind) -> list:
    return [e for e in d.events if e.kind is kind]
