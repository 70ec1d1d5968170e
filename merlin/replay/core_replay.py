"""Feed a recorded flight through the trusted core: what would Merlin have done, when, and why.

The log's states are resampled at a fixed rate (zero-order hold) into :class:`VehicleState`. The core is
told the vehicle was armed when the log says so (a forced ARM, as the log's own pre-flight checks
passed), and an experimental controller is simulated as if it held authority: a heartbeat every tick, a
position setpoint at the vehicle's own position (always consistent), a REQUEST from the first airborne
moment (repeated each second until granted) and the ACK of the grant it receives. Every revocation
that follows is what the core would have done to a controller flying exactly this trajectory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.envelope import envelope_values
from merlin.core.step import TrustedCore
from merlin.core.types import (
    AuthorityRequest,
    EventKind,
    ExperimentalInput,
    GcsCommand,
    GcsCommandKind,
    Inputs,
    NavMode,
    RequestKind,
    Setpoint,
    SetpointKind,
    VehicleState,
)
from merlin.replay.flightlog import FlightLog, hold

G = 9.80665


@dataclass(slots=True)
class ReplayResult:
    rate_hz: float
    t_s: np.ndarray
    authority: np.ndarray
    envelope: dict[str, np.ndarray]  # display units, by parameter name
    limits: dict[str, tuple[float, float, float]]  # name -> (min, max, duration_s), display units
    events: list[dict[str, Any]] = field(default_factory=list)
    first_airborne_s: float | None = None

    @property
    def revocations(self) -> list[dict[str, Any]]:
        return [e for e in self.events if e["type"] == "revoked"]


def states(log: FlightLog, t: np.ndarray) -> list[VehicleState]:
    pos = hold(log.pos_ned_m, t, (0.0, 0.0, 0.0))
    vel = hold(log.vel_ned_mps, t, (0.0, 0.0, 0.0))
    att = hold(log.att_rpy_rad, t, (0.0, 0.0, 0.0))
    rates = hold(log.rates_frd_radps, t, (0.0, 0.0, 0.0))
    acc = hold(log.accel_frd_mps2, t, (0.0, 0.0, -G))
    sig = hold(log.sigma_h_m, t, (0.5,))[:, 0]
    armed = hold(log.armed, t, (0.0,))[:, 0] > 0.5
    if log.landed is not None:
        landed = hold(log.landed, t, (1.0,))[:, 0] > 0.5
    else:  # no land detector in the log: on the ground while within 0.5 m of the start height
        landed = pos[:, 2] > pos[0, 2] - 0.5
    fix = hold(log.gps_fix, t, (3.0,))[:, 0]
    out = []
    for k in range(len(t)):
        nav = NavMode.GPS if fix[k] >= 3 else NavMode.INERTIAL
        out.append(VehicleState(
            pos_ned_m=(float(pos[k, 0]), float(pos[k, 1]), float(pos[k, 2])),
            vel_ned_mps=(float(vel[k, 0]), float(vel[k, 1]), float(vel[k, 2])),
            att_rpy_rad=(float(att[k, 0]), float(att[k, 1]), float(att[k, 2])),
            rates_frd_radps=(float(rates[k, 0]), float(rates[k, 1]), float(rates[k, 2])),
            accel_frd_mps2=(float(acc[k, 0]), float(acc[k, 1]), float(acc[k, 2])),
            pos_sigma_h_m=float(sig[k]), nav_mode=nav, armed=bool(armed[k]), landed=bool(landed[k])))
    return out


def replay(log: FlightLog, cfg: MerlinConfig, rate_hz: float = 50.0) -> ReplayResult:
    core_cfg = build_core_config(cfg, source=log.source)
    core = TrustedCore(core_cfg)
    dt = 1.0 / rate_hz
    t = np.arange(0.0, log.t_end_s, dt)
    sts = states(log, t)
    n = len(t)
    auth = np.zeros(n)
    env = {lim.name: np.zeros(n) for lim in core_cfg.envelope}
    events: list[dict[str, Any]] = []
    was_armed = False
    first_air: float | None = None
    last_req = -math.inf
    granted_seq = 0
    holding = False
    for k in range(n):
        now = float(t[k])
        s = sts[k]
        cmds: tuple[GcsCommand, ...] = ()
        if s.armed and not was_armed:
            cmds = (GcsCommand(GcsCommandKind.ARM, seq=k + 1, force=True),)
        elif was_armed and not s.armed:
            cmds = (GcsCommand(GcsCommandKind.DISARM, seq=k + 1, force=True),)
        was_armed = s.armed
        if first_air is None and s.armed and not s.landed:
            first_air = now
        reqs: list[AuthorityRequest] = []
        if granted_seq:
            reqs.append(AuthorityRequest(RequestKind.ACK, seq=granted_seq, t_s=now))
            granted_seq = 0
        elif first_air is not None and not holding and now - last_req >= 1.0 and not s.landed:
            reqs.append(AuthorityRequest(RequestKind.REQUEST, t_s=now))
            last_req = now
        sp = Setpoint(SetpointKind.POSITION, pos_ned_m=s.pos_ned_m, vel_ned_mps=s.vel_ned_mps, yaw_rad=s.att_rpy_rad[2])
        d = core.step(now, Inputs(state=s, experimental=ExperimentalInput(now, sp, now, tuple(reqs)),
                                  gcs_link_t_s=now, gcs_commands=cmds))
        for e in d.events:
            if e.kind is EventKind.GRANTED:
                granted_seq = e.seq
            if e.kind in (EventKind.GRANTED, EventKind.REVOKED, EventKind.DENIED, EventKind.AUTHORITY,
                          EventKind.BEHAVIOR, EventKind.MONITOR_TRIPPED):
                events.append(e.to_dict())
        holding = int(d.authority) == 2
        if not holding and any(e.kind is EventKind.REVOKED for e in d.events):
            last_req = math.inf  # a revoked controller does not ask again: one flight, one verdict
        auth[k] = float(d.authority)
        ev = envelope_values(s)
        for lim in core_cfg.envelope:
            env[lim.name][k] = ev[lim.index] * lim.display_scale
    limits = {lim.name: (lim.min_display, lim.max_display, lim.duration_s) for lim in core_cfg.envelope}
    return ReplayResult(rate_hz, t, auth, env, limits, events, first_air)
