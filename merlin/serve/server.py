"""``merlin serve``: the simulated vehicle and the trusted core in real time, speaking MAVLink like PX4 SITL.

This is the imperative shell around the pure core. One scheduler (the calling thread) drives the tick
with absolute deadlines from ``time.monotonic_ns``; between ticks it waits on the links' sockets with the
time that remains, never past the next deadline, and decodes what arrives (bounded per wake-up so a
flood cannot hold the tick). At each tick it turns what arrived into the core's :class:`Inputs`, runs one
:class:`sims.runner.ClosedLoop` tick (``sense`` then ``act``), answers the exchange events, and sends the
telemetry streams that are due: each stream has its own phase (:mod:`merlin.serve.streams`), so they
never pile onto one control tick.

Setpoints are coalesced: only the latest valid setpoint received before a tick matters to the core
(icd/ICD.md section 7), so a controller streaming faster than the tick is simply sampled.

Inputs (icd/ICD.md sections 4.2, 6, 8): controller HEARTBEAT (and, for controllers that heartbeat at
1 Hz like MAVSDK, any valid setpoint) -> the controller's liveness; SET_POSITION_TARGET_* /
SET_ATTITUDE_TARGET -> setpoint; MERLIN_AUTHORITY_REQUEST/ACK and the standard OFFBOARD mode command
(:class:`OffboardModeBridge`) -> exchange; GCS HEARTBEAT -> ground-station link time; MANUAL_CONTROL ->
operator RC; COMMAND_LONG/INT -> :func:`interpret_command`; mission (fence) and parameter protocols.

The effective configuration changes only on the ground, disarmed, between ticks: a fence upload or an
accepted PARAM_SET (icd/ICD.md sections 8.1, 8.2) builds the new configuration through the configuration
models, and :meth:`Server._install_config` rebuilds the trusted core from it, records ``config_changed``
with the old and new SHA-256 and rewrites ``effective_config.yaml`` in the output directory, so what was
flown is always on disk next to the logs.
"""

from __future__ import annotations

import contextlib
import gc
import itertools
import logging
import math
import os
import select
import signal
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from merlin.autopilot import fixedwing_mission
from merlin.config.loader import config_sha256
from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.step import TrustedCore
from merlin.core.types import (
    Authority,
    AuthorityRequest,
    Behavior,
    Decision,
    Event,
    EventKind,
    GcsCommand,
    GcsCommandKind,
    MonitorId,
    NavMode,
    OperatorInput,
    ReasonCode,
    RequestKind,
    Setpoint,
    SetpointKind,
    VehicleState,
)
from merlin.geodesy import LocalFrame
from merlin.link import inbound as i
from merlin.link import outbound as o
from merlin.link.commands import (
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_DENIED,
    MAV_RESULT_UNSUPPORTED,
    MAVLINK_MSG_ID_AUTOPILOT_VERSION,
    MAVLINK_MSG_ID_HOME_POSITION,
    LinkRole,
    MissionCurrent,
    OffboardModeBridge,
    Refused,
    RequestMessage,
    SetMessageInterval,
    command_ack,
    interpret_command,
)
from merlin.link.endpoint import MavlinkEndpoint, read_stamped
from merlin.link.fence_protocol import FenceDescription, FenceProtocol
from merlin.link.mission_protocol import (
    MissionEnd,
    MissionPlan,
    MissionProtocol,
    check_jump_against_fence,
    check_legs_against_fence,
    plan_from_config,
    waypoint_at_or_after,
)
from merlin.link.mission_transfer import MAV_MISSION_ACCEPTED, MAV_MISSION_TYPE_ALL, MAV_MISSION_TYPE_MISSION
from merlin.link.params import ParamProtocol, ParamWrite, int32_params, published_params, with_param
from merlin.link.px4_modes import OFFBOARD
from merlin.link.security import LinkPolicy
from merlin.link.signing import write_key_file
from merlin.link.tlog import TlogWriter
from merlin.pipeline import InputBuilder
from merlin.serve.link_security import LinkSetup, describe
from merlin.serve.offboard_takeoff import HANDOVER_MARGIN_M, Facts, OffboardTakeoff
from merlin.serve.records import EventLog, TickStats, write_effective_config
from merlin.serve.streams import CONTROLLER_RATES_HZ, GCS_RATES_HZ, Stream, plan_streams, replan

log = logging.getLogger("merlin.serve")

# MAV_SYS_STATUS_SENSOR bits (common.xml): 3D gyro, accel, mag, absolute pressure, GPS, pre-arm check
SENSOR_GPS = 32
SENSORS_PRESENT = 1 | 2 | 4 | 8 | SENSOR_GPS | (1 << 28)
REVOKE_REPEATS_S = (1.0, 2.0)  # MERLIN_AUTHORITY_REVOKE is re-sent 1 s and 2 s after (ICD 4.3)
RESYNC_TICKS = 200  # more than this far behind, the schedule is re-anchored instead of caught up
MAX_DATAGRAMS_PER_READ = 64  # per link per wake-up: a flood waits in the socket buffer, not in the tick
# Waiting for a deadline (see Server.run): sleep in select(2), whose timeout has microsecond resolution
# (poll(2) and epoll take whole milliseconds, and Python rounds them up: a tick started up to 1 ms late),
# to SPIN_NS before the deadline, then spin. No datagram is decoded closer than DRAIN_GUARD_NS to a
# deadline, and decoding while waiting stops at that guard: what is left waits in the link's backlog.
SPIN_NS = 150_000
DRAIN_GUARD_NS = 400_000
# At a tick's start, what arrived since the last wake-up is decoded for at most this long (a setpoint sent
# just before the tick is used by it); the rest is decoded while waiting for the next tick.
TICK_DRAIN_BUDGET_NS = 1_000_000
FSYNC_INTERVAL_S = 1.0
BULK_PER_TICK = 2  # bulk messages per link per tick (an encode costs ~0.1 ms, docs/benchmarks/link.md)
GC_EVERY_TICKS = 250  # a young-generation collection, done by hand right after a tick (small: < 1 ms)
GC_MIDDLE_EVERY = 20  # every 20th of them collects the middle generation too
GC_BULK_OBJECTS = 500  # more new objects than this at a collection point are frozen, not traversed
ULOG_RATE_HZ = 50.0  # flight.ulg's sample rate, as merlin sim's log (scenario log_rate_hz default)
EFFECTIVE_CONFIG = "effective_config.yaml"  # in the output directory, next to flight.tlog and events.jsonl
# PARAM_SET is accepted on the ground station's link only: the experimental controller is untrusted and must
# never rewrite the limits that judge it (icd/ICD.md section 8.2)
PARAM_WRITE_LINKS = frozenset({"gcs"})
#: The messages :meth:`Server._stream_messages` produces (streams, and MAV_CMD_REQUEST_MESSAGE answers).
STREAM_NAMES = frozenset({
    "HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "GPS_RAW_INT", "VFR_HUD", "SYS_STATUS",
    "EXTENDED_SYS_STATE", "HOME_POSITION", "MERLIN_AUTHORITY_STATUS", "MERLIN_ENVELOPE_STATUS", "MISSION_CURRENT",
})


@dataclass(frozen=True, slots=True)
class UdpLinkSpec:
    bind: tuple[str, int]
    remote: tuple[str, int]


@dataclass(frozen=True, slots=True)
class ServeOptions:
    config: MerlinConfig = field(default_factory=MerlinConfig)
    config_source: str = "<built-in default>"
    vehicle: str = "quadrotor_default"  # sims.runner.make_loop's choice: a multirotor file or a JSBSim fixed wing
    rate_hz: float = 250.0
    # the trusted core's period and the IMU voter's and fusion EKF's (a scenario's core_dt_s and nav_dt_s):
    # "auto" 10 ms rounded down to whole ticks (sims.scenario.default_period), None every tick, else a whole
    # number of ticks (merlin serve --core-dt-s / --nav-dt-s checks it)
    core_dt_s: float | str | None = "auto"
    nav_dt_s: float | str | None = "auto"
    speedup: float = 1.0
    system_id: int = 1
    component_id: int = 1
    gcs: UdpLinkSpec | None = UdpLinkSpec(("0.0.0.0", 18570), ("127.0.0.1", 14550))
    controller: UdpLinkSpec | None = UdpLinkSpec(("0.0.0.0", 14580), ("127.0.0.1", 14540))
    serial: tuple[str, int] | None = None  # (device, baud): the controller link on a serial port instead
    out_dir: Path = Path("out/serve")
    duration_s: float | None = None
    controller_policy: LinkPolicy = field(default_factory=lambda: LinkPolicy(name="controller"))
    gcs_policy: LinkPolicy = field(default_factory=lambda: LinkPolicy(name="gcs"))
    # where a key provisioned with SETUP_SIGNING is written, per link (links.<name>.signing.key_file)
    controller_key_file: Path | None = None
    gcs_key_file: Path | None = None
    setpoint_liveness: bool = True  # a valid setpoint also counts as controller liveness (see module doc)
    tune_gc: bool = True
    realtime_priority: int = 0  # >0: run the scheduler thread SCHED_FIFO at this priority (Linux), as the FCU does
    params_locked: bool = False  # refuse every PARAM_SET (--params-locked; links.params_locked does the same)


@dataclass
class _LinkState:
    name: str
    role: LinkRole
    endpoint: MavlinkEndpoint
    # bulk messages (the envelope burst, a parameter list) are sent a few per tick, never all in one
    bulk: deque[o.OutMessage] = field(default_factory=deque)
    # datagrams read from the socket but not yet decoded (decoding is time-bounded, see Server._drain)
    # (datagram, sender address, monotonic ns of its arrival: the kernel's receive time, or else its read)
    backlog: deque[tuple[bytes, Any, int]] = field(default_factory=deque)


@dataclass
class _Pending:
    """What arrived since the previous tick, already decoded; becomes the tick's Inputs."""

    # (t, SetpointIn | GlobalSetpointIn | AttitudeTargetIn, monotonic ns of its arrival)
    setpoint: tuple[float, Any, int] | None = None
    coalesced: int = 0  # setpoints superseded by a later one before the tick
    requests: list[AuthorityRequest] = field(default_factory=list)
    commands: list[GcsCommand] = field(default_factory=list)


def _scenario(opts: ServeOptions, estimator: str) -> Any:
    """The simulated flight serve ticks: the vehicle, its tick (1/rate), the core's and the filter's periods."""
    from sims.scenario import Scenario

    return Scenario.model_validate({"name": "serve", "duration_s": 7200.0, "dt_s": 1.0 / opts.rate_hz,
                                    "vehicle": opts.vehicle, "estimator": estimator, "core_dt_s": opts.core_dt_s,
                                    "nav_dt_s": opts.nav_dt_s})


class Server:
    """One ``merlin serve`` process: see the module doc. ``run()`` returns when the duration elapses or
    ``stop()`` is called (SIGINT/SIGTERM)."""

    def __init__(self, opts: ServeOptions) -> None:
        from sims.runner import FIXED_WING_VEHICLES, make_loop
        from sims.scenario import estimator_note

        self.opts = opts
        self.cfg = opts.config
        self.dt = 1.0 / opts.rate_hz
        # the vehicle on the ground at home; a fixed wing rests on its catapult until TAKEOFF launches it.
        # Both vehicles are served on the fusion EKF, as `merlin sim` flies them (the fixed wing's restarted in
        # the air at the catapult's release). The multirotor's stock-client flows once failed on it: the EKF's
        # smooth vertical velocity showed the climb Merlin flew an experimental position setpoint at (the 3 m/s
        # clamp, the envelope's own limit) settling from above for 0.5 s, which the stand-in's noise had hidden;
        # Merlin now climbs towards a position setpoint at its own climb speed (merlin.core.shaping,
        # scenario offboard_position_climb_ekf).
        self.estimator = "ekf"
        self.estimator_note = estimator_note(self.estimator)
        self.loop = make_loop(_scenario(opts, self.estimator), self.cfg, opts.config_source)
        self.mav_type = o.MAV_TYPE_FIXED_WING if opts.vehicle in FIXED_WING_VEHICLES else o.MAV_TYPE_QUADROTOR
        h = self.cfg.home
        self.frame = LocalFrame(h.lat_deg, h.lon_deg, h.alt_amsl_m)
        opts.out_dir.mkdir(parents=True, exist_ok=True)
        # fsync (power-loss safety) happens in a helper thread, never in the tick: on a busy disk one fsync
        # takes tens of milliseconds. A killed process loses nothing either way (one write(2) per record).
        self.tlog = TlogWriter(opts.out_dir / "flight.tlog", fsync_interval_s=None)
        self.events = EventLog(opts.out_dir / "events.jsonl")
        # flight.ulg: the flight as PX4's topics and Merlin's at 50 Hz, for Flight Review and PlotJuggler
        # (merlin.ulog.flight; docs/field-tools.md), appended a second at a time
        from merlin.ulog.flight import FlightRecorder, flight_meta

        self.ulog = FlightRecorder(
            opts.out_dir / "flight.ulg",
            flight_meta(self.cfg, opts.vehicle in FIXED_WING_VEHICLES,
                        {"merlin_config_sha256": config_sha256(self.cfg), "merlin_serve": 1}, "MERLIN_SERVE"),
            self.loop.core_cfg.envelope, every_ticks=round(opts.rate_hz / ULOG_RATE_HZ), fence=self.loop.core_cfg.fence)
        self._syncer = threading.Thread(target=self._sync_files, name="serve-fsync", daemon=True)
        self.links: list[_LinkState] = self._open_links(opts)
        sid, cid = opts.system_id, opts.component_id
        self.tick_hz = opts.rate_hz
        self.defaults = {"controller": CONTROLLER_RATES_HZ, "gcs": GCS_RATES_HZ}
        self.streams: tuple[Stream, ...] = plan_streams(
            {ls.name: self.defaults[ls.name] for ls in self.links}, self.tick_hz)
        self.bridge = OffboardModeBridge()
        self.fence = FenceProtocol(sid, cid, FenceDescription.from_config(self.cfg.geofence, self.frame))
        self._fence_link: _LinkState | None = None
        t_ = self.cfg.trusted
        self.mission = MissionProtocol(sid, cid, self.frame, plan_from_config(
            t_.mission_ned_m, t_.mission_speed_mps, t_.mission_end, self.frame))
        self.mission.check = self._check_mission
        self._mission_link: _LinkState | None = None
        self._manual_refused: set[str] = set()  # links whose MANUAL_CONTROL was refused (recorded once each)
        self._mission_reached = -1  # the highest item sequence reported with MISSION_ITEM_REACHED this flight
        self._mission_current = -1  # the last MISSION_CURRENT seq sent
        self._mission_complete = False  # flown to its end this flight (its end item reported on landing)
        self._mission_jumps: dict[int, int] = {}  # MISSION_CURRENT commands awaiting the core: seq -> waypoint
        # the fixed wing's mission and GOTO/ORBIT loiters (merlin.autopilot.fixedwing_mission): what its stage
        # reads beyond the core's decision
        stage = self._fw_stage()
        if stage is not None:
            stage.fw_mission = fixedwing_mission.FixedWingMission(arbiter=lambda: self.loop.core.state.arbiter)
        self._fw_target_seq = 0  # the core's GOTO/ORBIT count the stage flies
        self._fw_mission_done = False  # the fixed wing flew its mission to the end (its end item commanded)
        self._was_armed = False
        self.limits = self.cfg.envelope.resolve(self.cfg.envelope.active_stage)
        self.cfg_sha256 = config_sha256(self.cfg)
        self.params_locked = opts.params_locked or self.cfg.links.params_locked
        self.params = ParamProtocol(published_params(self.cfg), self._check_param, locked=self.params_locked,
                                    write_links=PARAM_WRITE_LINKS, int32=int32_params())
        self.effective_config = opts.out_dir / EFFECTIVE_CONFIG
        self._write_effective_config()
        self.pending = _Pending()
        self.inputs = InputBuilder()  # the core's inputs from what the links delivered (_tick)
        self.hb_t: float | None = None
        self.gcs_t: float | None = None
        self.rc_t: float | None = None
        self.op = OperatorInput()
        self.sp: Setpoint | None = None
        self.sp_t: float | None = None
        self.decision: Decision | None = None
        self._cmd_seq = 0
        self._cmd_waiting: dict[int, tuple[_LinkState, i.CommandIn, tuple[int, int]]] = {}
        self._request_ids: list[tuple[_LinkState, int, tuple[int, int]]] = []  # dialect requests awaiting answer
        self._exchange_peer: tuple[_LinkState, tuple[int, int]] | None = None
        self._grant_seq_active = 0
        self._revoke_repeats: list[tuple[float, o.OutMessage]] = []
        self._last_reason = ReasonCode.NONE
        self._last_revoke_t: float | None = None
        self._controller_sender: tuple[int, int] | None = None
        self._sp_rx_t: float | None = None  # when the latest valid setpoint arrived (core clock)
        self.takeoff = OffboardTakeoff()  # PX4's offboard take-off flow (merlin.serve.offboard_takeoff)
        self._takeoff_cmd: tuple[_LinkState, i.CommandIn, tuple[int, int]] | None = None
        # the standard OFFBOARD request being decided (command, sender, received), for :meth:`_switch_denied`
        self._standard_request: tuple[i.CommandIn, tuple[int, int], float] | None = None
        self._requeued = False  # that request, refused at the switch on the liveness rule, to be asked again
        self._stop = False
        self._read_ns = 0  # when the datagram being handled was read from its socket (monotonic ns)
        self._t0_ns = time.monotonic_ns()
        self.stats = TickStats(period_ns=round(self.dt / opts.speedup * 1e9))
        self.on_tick: Callable[[Server], None] | None = None  # test/benchmark hook, after each tick

    def _open_links(self, opts: ServeOptions) -> list[_LinkState]:
        """The controller's link (serial or UDP) and the ground station's, as the options give them."""
        links: list[_LinkState] = []
        sid, cid = opts.system_id, opts.component_id
        if opts.serial is not None:
            ep = MavlinkEndpoint.serial(opts.controller_policy, opts.serial[0], opts.serial[1], sid, cid, self.tlog,
                                        key_file=opts.controller_key_file)
            links.append(_LinkState("controller", LinkRole.CONTROLLER, ep))
        elif opts.controller is not None:
            ep = MavlinkEndpoint.udp(opts.controller_policy, opts.controller.bind, opts.controller.remote, sid, cid,
                                     self.tlog, key_file=opts.controller_key_file)
            links.append(_LinkState("controller", LinkRole.CONTROLLER, ep))
        if opts.gcs is not None:
            ep = MavlinkEndpoint.udp(opts.gcs_policy, opts.gcs.bind, opts.gcs.remote, sid, cid, self.tlog,
                                     key_file=opts.gcs_key_file)
            links.append(_LinkState("gcs", LinkRole.GCS, ep))
        for ls in links:
            enable = getattr(ls.endpoint.transport, "enable_kernel_stamps", None)
            if enable is not None:
                enable()  # when each datagram arrived, for the catch-up after a stall (Server._drain)
        return links

    # ---------------------------------------------------------------------------------- time

    @property
    def t(self) -> float:
        """The core's clock: the time of the next tick."""
        return self.loop.t

    def _boot_ms(self) -> int:
        return int(self.loop.t * 1000.0) & 0xFFFFFFFF

    # ------------------------------------------------------------------------------- sending

    def _send(self, ls: _LinkState, msg: o.OutMessage) -> None:
        ls.endpoint.send(msg)

    def _broadcast(self, msg: o.OutMessage) -> None:
        for ls in self.links:
            ls.endpoint.send(msg)

    def _in_authority(self) -> bool:
        """Whether the experimental controller holds authority in the latest decision."""
        return self.decision is not None and self.decision.authority is Authority.EXPERIMENTAL

    def _controller_link(self) -> _LinkState | None:
        for ls in self.links:
            if ls.role is LinkRole.CONTROLLER:
                return ls
        return None

    # ------------------------------------------------------------------------------- input

    def _on_received(self, ls: _LinkState, rx: i.Received) -> None:
        m = rx.msg
        t = rx.t_s
        sender = (rx.system_id, rx.component_id)
        if isinstance(m, i.HeartbeatIn):
            # On the controller link every HEARTBEAT is the controller's, whatever type it declares (MAVSDK
            # declares a ground station by default): PX4 does not look at the type either. The ground-station
            # link time comes from the GCS link only, where the operator's authority lives (ICD section 6).
            if ls.role is LinkRole.CONTROLLER:
                self.hb_t = t
                self._controller_sender = sender
                self.stats.record_controller_alive(self._read_ns, t, self._in_authority())
            else:
                self.gcs_t = t
            return
        if isinstance(m, (i.SetpointIn, i.GlobalSetpointIn, i.AttitudeTargetIn)):
            if ls.role is not LinkRole.CONTROLLER:
                return  # setpoints are the controller's (ICD 4.2); a GCS flies through MANUAL_CONTROL
            if self.pending.setpoint is not None:
                self.pending.coalesced += 1
            self.pending.setpoint = (t, m, self._read_ns)
            self._sp_rx_t = t
            if self.opts.setpoint_liveness:
                self.hb_t = t
                self.stats.record_controller_alive(self._read_ns, t, self._in_authority())
            ack = self.bridge.on_setpoint(t)
            if ack is not None:
                self.pending.requests.append(ack)
            return
        if isinstance(m, i.AuthorityRequestIn):
            self.pending.requests.append(m.to_core(t))
            if m.kind is not RequestKind.RELEASE:
                self._request_ids.append((ls, m.request_id, sender))
                self._exchange_peer = (ls, sender)
            return
        if isinstance(m, i.AuthorityAckIn):
            self.pending.requests.append(m.to_core(t))
            return
        if isinstance(m, i.ManualControlIn):
            if ls.role is not LinkRole.GCS:
                # Operator authority lives on the ground station's link (icd/ICD.md sections 4.2 and 13): PX4
                # takes MANUAL_CONTROL from the offboard link, Merlin never lets the experimental controller
                # become the operator. Recorded once per link, not per message (it streams at 10-50 Hz).
                if ls.name not in self._manual_refused:
                    self._manual_refused.add(ls.name)
                    self.events.write({"t": t, "type": "manual_control_refused", "link": ls.name,
                                       "sender": list(sender), "detail": "MANUAL_CONTROL is the GCS link's"})
                    self._send(ls, o.StatusTextOut(o.MAV_SEVERITY_WARNING,
                                                   "Merlin: MANUAL_CONTROL ignored on this link (operator: GCS link)"))
                return
            self.rc_t = t
            self.op = OperatorInput(t, bool(m.buttons & 1), m.roll, m.pitch, m.yaw, m.throttle)
            return
        if isinstance(m, i.CommandIn):
            self._on_command(ls, rx, m, sender)
            return
        if isinstance(m, (i.ParamRequestListIn, i.ParamRequestReadIn, i.ParamSetIn)):
            outs = self.params.handle(rx)
            changed = False
            for w in self.params.take_writes():  # (one at most: this is one message)
                outs, changed = self._on_param_write(w, outs)
            # a changed value goes to every link, as the protocol asks, so every ground station's list stays
            # true; anything else answers the sender's link only
            for dest in (self.links if changed else [ls]):
                dest.bulk.extend(outs)
            return
        if isinstance(m, i.MissionSetCurrentIn):
            self._on_mission_current(ls, rx.t_s, m.seq, None, sender)
            return
        if hasattr(m, "mission_type"):
            self._on_mission_protocol(ls, rx, m, sender)

    def _hold_on_ground(self, ls: _LinkState, m: Any, sender: tuple[int, int], t_s: float) -> None:
        """Accept a controller link's HOLD on the ground (PX4 accepts Hold there; nothing flies)."""
        self._send(ls, command_ack(m, sender, MAV_RESULT_ACCEPTED))
        self.events.write({"t": t_s, "type": "hold_on_ground", "link": ls.name,
                           "detail": "HOLD on the ground from the controller link: accepted, nothing flies"})

    def _on_command(self, ls: _LinkState, rx: i.Received, m: i.CommandIn, sender: tuple[int, int]) -> None:
        intents = interpret_command(m, ls.role, self.frame.alt0_amsl_m, rx.t_s, frame=self.frame,
                                    pos_ned_m=self.loop.state.pos_ned_m,
                                    fixed_wing=self.mav_type == o.MAV_TYPE_FIXED_WING)
        acked = False
        for intent in intents:
            if isinstance(intent, GcsCommand):
                if intent.kind is GcsCommandKind.HOLD and ls.role is LinkRole.CONTROLLER and self.loop.state.landed:
                    # MAVSDK's offboard.stop() (AUTO.LOITER) after Merlin took authority back and landed: PX4
                    # accepts Hold on the ground and the vehicle stays there; so does Merlin, without asking the
                    # core for a HOLD it refuses on the ground (the RELEASE before it went to the core as usual)
                    self._hold_on_ground(ls, m, sender, rx.t_s)
                    acked = True
                    continue
                intent, refused = self._fixed_wing_loiter(intent)
                if refused is None:
                    refused = self._mission_start_refused(intent)
                    refused = None if refused is None else f"mission not started: {refused}"
                if refused is not None:  # as PX4's mission feasibility check at start, with Merlin's leg check
                    self._send(ls, command_ack(m, sender, MAV_RESULT_DENIED))
                    self._broadcast(o.StatusTextOut(o.MAV_SEVERITY_WARNING, f"Merlin: {refused}"))
                    self.events.write({"t": rx.t_s, "type": "command_refused", "link": ls.name,
                                       "command": m.command, "detail": refused})
                    acked = True
                    continue
                self._cmd_seq += 1
                self.pending.commands.append(replace(intent, seq=self._cmd_seq))
                self._cmd_waiting[self._cmd_seq] = (ls, m, sender)
                acked = True
            elif isinstance(intent, AuthorityRequest):
                if intent.kind is RequestKind.REQUEST:
                    acked = True
                    if self.bridge.is_repeat(m, sender):
                        self._send(ls, self.bridge.hold(self.bridge.held_since_s or rx.t_s))
                        continue
                    if self._attitude_on_ground(rx.t_s):
                        # the controller flies its own take-off, as on PX4; the core judges the request as any
                        # other and defers the altitude floors for that take-off alone (icd/ICD.md 6.1)
                        self.events.write({"t": rx.t_s, "type": "offboard_takeoff", "phase": "attitude",
                                           "link": ls.name, "detail": "OFFBOARD on the ground on attitude"
                                           " setpoints: the controller's take-off, supervised; the floors apply"
                                           " once above them"})
                    elif self._accept_on_ground(rx.t_s):
                        self.takeoff.accept()
                        self._takeoff_cmd = (ls, m, sender)
                        self._send(ls, command_ack(m, sender, MAV_RESULT_ACCEPTED))
                        if self.decision is not None:
                            self._send(ls, self._heartbeat(ls, self.decision))
                        self.events.write({"t": rx.t_s, "type": "offboard_takeoff", "phase": "accepted",
                                           "link": ls.name, "detail": "OFFBOARD on the ground: Merlin's take-off"
                                           " flies at the arming, the request follows in the air"})
                        continue
                    self.bridge.requested(m, sender)
                    self._exchange_peer = (ls, sender)
                    self._standard_request, self._requeued = (m, sender, rx.t_s), False
                    if self._hold_standard_request(rx.t_s):
                        self._send(ls, self.bridge.hold(rx.t_s))
                        self.events.write({"t": rx.t_s, "type": "offboard_request_held", "link": ls.name,
                                           "detail": self._hold_detail(rx.t_s)})
                        continue
                elif intent.kind is RequestKind.RELEASE:
                    self._cancel_standard_request(rx.t_s, "released by a mode command")
                self.pending.requests.append(intent)
            elif isinstance(intent, RequestMessage):
                if self._can_send(intent.message_id):
                    self._send(ls, command_ack(m, sender, MAV_RESULT_ACCEPTED))
                    self._send_requested(ls, intent.message_id)
                else:  # answered at once, so a ground station moves on instead of waiting for its timeout
                    self._send(ls, command_ack(m, sender, MAV_RESULT_UNSUPPORTED))
                    self.events.write({"t": rx.t_s, "type": "command_refused", "link": ls.name,
                                       "command": m.command, "detail": f"message {intent.message_id} not provided"})
                acked = True
            elif isinstance(intent, MissionCurrent):
                self._on_mission_current(ls, rx.t_s, intent.seq, m, sender)
                acked = True
            elif isinstance(intent, SetMessageInterval):
                self._set_interval(ls, m, sender, intent)
                acked = True
            elif isinstance(intent, Refused):
                self._send(ls, command_ack(m, sender, intent.result))
                self.events.write({"t": rx.t_s, "type": "command_refused", "link": ls.name, "command": m.command,
                                   "detail": intent.detail})
                acked = True
        if not acked:  # a RELEASE alone (cannot happen with today's mapping) still gets an answer
            self._send(ls, command_ack(m, sender, MAV_RESULT_ACCEPTED))

    # ------------------------------------------------------------------ standard OFFBOARD requests

    def _streaming(self, t: float) -> bool:
        """Whether the controller's setpoints stream as PX4 counts it: the latest within
        ``links.offboard_loss_timeout_s`` (PX4's COM_OF_LOSS_T)."""
        return self._sp_rx_t is not None and t - self._sp_rx_t <= self.cfg.links.offboard_loss_timeout_s

    def _alive_s(self, t: float) -> float:
        """How long the controller's liveness (heartbeat or setpoint) has been unbroken at ``t``, as the
        core counts it for ``handover.heartbeat_alive_min_s`` (0 while it is lapsed)."""
        since = self.loop.core.state.hb_alive_since_s
        if since is None or self.hb_t is None or t - self.hb_t > self.cfg.watchdogs.controller_heartbeat.timeout_s:
            return 0.0
        return max(0.0, t - since)

    def _can_decide(self, t: float, since: float) -> bool:
        """Whether a request kept since ``since`` for Merlin's liveness rule goes to the core now: the rule
        met, the stream lost, or ``links.offboard_request_wait_s`` over."""
        need = self.cfg.handover.heartbeat_alive_min_s
        return (not self._streaming(t) or self._alive_s(t) + 1e-9 >= need
                or t - since >= self.cfg.links.offboard_request_wait_s)

    def _hold_standard_request(self, t: float) -> bool:
        """Whether a standard OFFBOARD request is held instead of decided now: PX4 would accept it (setpoints
        streaming) and only Merlin's heartbeat rule is not met yet. Anything else the core decides at once,
        with its reason: a controller that never streamed is denied."""
        need = self.cfg.handover.heartbeat_alive_min_s
        return self.loop.armed and self._streaming(t) and self._alive_s(t) + 1e-9 < need

    def _hold_detail(self, t: float) -> str:
        need = self.cfg.handover.heartbeat_alive_min_s
        return (f"setpoints streaming; controller alive {self._alive_s(t):.2f} s of the {need:.2f} s required:"
                " held (IN_PROGRESS) until then")

    def _accept_on_ground(self, t: float) -> bool:
        """Whether an OFFBOARD request starts PX4's offboard take-off flow: on the ground (disarmed, as PX4's
        tutorial asks, or armed, as MAVSDK's examples do), with position or velocity setpoints streaming
        (merlin.serve.offboard_takeoff)."""
        sp = self.pending.setpoint[1] if self.pending.setpoint is not None else None
        kind_ok = isinstance(sp, (i.SetpointIn, i.GlobalSetpointIn)) or (
            sp is None and self.sp is not None and self.sp.kind is not SetpointKind.ATTITUDE)
        return (bool(self.loop.state.landed) and self._streaming(t) and kind_ok
                and self.takeoff.phase.value == "idle")

    def _attitude_on_ground(self, t: float) -> bool:
        """Whether an OFFBOARD request comes on the ground with attitude setpoints streaming. Such a request
        is not served by Merlin's take-off (icd/ICD.md 6.1): an attitude setpoint holds no height, so a
        hand-over after Merlin's climb would give an open-loop collective to the controller at the lowest
        height the envelope allows. It goes to the core as PX4 takes it, and the controller's thrust flies
        the take-off, supervised from the first tick (the altitude floors once the vehicle is above them)."""
        sp = self.pending.setpoint[1] if self.pending.setpoint is not None else None
        attitude = (sp is None and self.sp is not None and self.sp.kind is SetpointKind.ATTITUDE) or (
            isinstance(sp, i.AttitudeTargetIn))
        return (bool(self.loop.state.landed) and self._streaming(t) and attitude
                and self.takeoff.phase.value == "idle")

    def _handover_alt_m(self) -> float:
        """The height from which the envelope allows a grant after Merlin's take-off."""
        lim = self.limits.get("altitude_m")
        low = lim.min if lim is not None and lim.enabled else 0.0
        return max(low, 0.0) + HANDOVER_MARGIN_M

    def _advance_takeoff(self, t: float, p: _Pending) -> None:
        """One tick of PX4's offboard take-off flow: command the take-off at the arming, send the request
        once high enough, show the truth again when it ends."""
        d = self.decision
        if d is None or not self.takeoff.shows_offboard:
            return
        s = self.loop.state
        need = self.cfg.handover.heartbeat_alive_min_s
        step = self.takeoff.step(Facts(bool(d.armed), bool(s.landed), s.alt_m, d.authority, d.behavior,
                                       self._streaming(t), self._handover_alt_m(), self._alive_s(t) + 1e-9 >= need,
                                       t, self.cfg.links.offboard_request_wait_s))
        if step.takeoff:
            self._cmd_seq += 1
            p.commands.append(GcsCommand(GcsCommandKind.TAKEOFF, param=math.nan, seq=self._cmd_seq))
            self.events.write({"t": t, "type": "offboard_takeoff", "phase": "climbing",
                               "detail": f"Merlin's take-off to {self.cfg.trusted.takeoff_altitude_m:g} m;"
                               f" the request at {self._handover_alt_m():g} m"})
        if step.waiting:
            self.events.write({"t": t, "type": "offboard_takeoff", "phase": "waiting", "alt_m": round(s.alt_m, 3),
                               "detail": f"controller alive {self._alive_s(t):.2f} s of the "
                               f"{self.cfg.handover.heartbeat_alive_min_s:.2f} s required: the request waits (at most"
                               f" {self.cfg.links.offboard_request_wait_s:g} s, links.offboard_request_wait_s)"})
        if step.request and self._takeoff_cmd is not None:
            ls, cmd, sender = self._takeoff_cmd
            self.bridge.requested(cmd, sender, answered=True)
            self._exchange_peer = (ls, sender)
            p.requests.append(AuthorityRequest(RequestKind.REQUEST, t_s=t))
            self.events.write({"t": t, "type": "offboard_takeoff", "phase": "requested", "alt_m": round(s.alt_m, 3)})
        if step.ended:
            self._end_takeoff(t, step.ended)

    def _takeoff_denied(self, e: Event) -> None:
        """The take-off flow's request denied, when asked or at the exchange's switch: waiting again for a
        denial on Merlin's liveness rule alone (OffboardTakeoff.denied), else the flow ends and every link
        shows the truth (a denial at the switch used to leave the controller's link showing OFFBOARD while
        Merlin held: the regression test_a_stream_that_stutters_during_merlins_take_off_is_handed_over_as_px4_would)."""
        t = self.t
        liveness = e.reason.code is ReasonCode.HEARTBEAT_NOT_ESTABLISHED
        if self.takeoff.denied(t, liveness, self._streaming(t), self.cfg.links.offboard_request_wait_s):
            self.events.write({"t": t, "type": "offboard_takeoff", "phase": "waiting", "alt_m":
                               round(self.loop.state.alt_m, 3), "detail": f"denied: {e.reason.describe()}; setpoints "
                               "streaming: the request goes again once the rule is met"})
            return
        self._end_takeoff(t, f"denied: {e.reason.describe()}")

    def _switch_denied(self, e: Event) -> None:
        """A standard OFFBOARD request's grant refused at the exchange's switch. Its sender was answered
        ACCEPTED at the grant (as PX4 answers), so a refusal on Merlin's liveness rule alone (the link went
        quiet between the grant and its ACK, shorter than PX4's COM_OF_LOSS_T) is asked again, silently, once
        the rule is met, while the setpoints stream and within ``links.offboard_request_wait_s`` of the
        request; any other refusal stands (its DENY message and STATUSTEXT say why)."""
        assert self._standard_request is not None
        t = self.t
        received = self._standard_request[2]
        if (e.reason.code is ReasonCode.HEARTBEAT_NOT_ESTABLISHED and self._streaming(t)
                and t - received < self.cfg.links.offboard_request_wait_s):
            self._requeued = True
            self.events.write({"t": t, "type": "offboard_request_held", "detail": f"denied at the switch: "
                               f"{e.reason.describe()}; setpoints streaming: asked again once the rule is met"})
            return
        self._standard_request, self._requeued = None, False

    def _advance_requeued(self, t: float, requests: list[AuthorityRequest]) -> None:
        """At a tick: the request :meth:`_switch_denied` kept goes to the core again once it can decide (the
        rule met, the stream lost, or the wait over), answered to no one (its sender has its ACCEPTED)."""
        if not self._requeued or self._standard_request is None:
            return
        cmd, sender, received = self._standard_request
        if not self._can_decide(t, received):
            return
        self._requeued = False
        self.bridge.requested(cmd, sender, answered=True)
        requests.append(AuthorityRequest(RequestKind.REQUEST, t_s=t))
        self.events.write({"t": t, "type": "offboard_request_released", "requeued": True,
                           "streaming": self._streaming(t), "alive_s": round(self._alive_s(t), 4)})

    def _cancel_standard_request(self, t: float, why: str) -> None:
        """A controller leaving OFFBOARD (a mode command from its link) while its OFFBOARD request is held or
        its take-off flow runs: the held request is answered DENIED and never goes to the core; the flow ends."""
        self._standard_request, self._requeued = None, False
        held = self.bridge.cancel_held()
        if held is not None and self._exchange_peer is not None:
            self._send(self._exchange_peer[0], held)
            self.events.write({"t": t, "type": "offboard_request_released", "cancelled": why})
        if self.takeoff.shows_offboard:
            self._end_takeoff(t, why)

    def _end_takeoff(self, t: float, why: str) -> None:
        self.takeoff.end()
        self.events.write({"t": t, "type": "offboard_takeoff", "phase": "ended", "detail": why})
        if self.decision is not None:
            for ls in self.links:
                self._send(ls, self._heartbeat(ls, self.decision))

    def _heartbeat(self, ls: _LinkState, d: Decision) -> o.HeartbeatOut:
        """HEARTBEAT for ``ls``: the controller's link shows OFFBOARD during the offboard take-off flow, as
        PX4 would show it; every other link (and that one otherwise) the truth."""
        hb = o.heartbeat_from_decision(d, self.mav_type)
        if ls.role is LinkRole.CONTROLLER and self.takeoff.shows_offboard:
            return replace(hb, mode=OFFBOARD)
        return hb

    def _advance_held_request(self, t: float, requests: list[AuthorityRequest]) -> None:
        """At a tick: pass a held standard request to the core once it can decide (the heartbeat rule met,
        the stream lost, or ``links.offboard_request_wait_s`` over), else repeat IN_PROGRESS when due."""
        held = self.bridge.held_since_s
        if held is None:
            return
        if self._can_decide(t, held):
            self.bridge.release()
            requests.append(AuthorityRequest(RequestKind.REQUEST, t_s=t))
            self.events.write({"t": t, "type": "offboard_request_released", "held_s": round(t - held, 4),
                               "streaming": self._streaming(t), "alive_s": round(self._alive_s(t), 4)})
            return
        ack = self.bridge.progress(t)
        if ack is not None and self._exchange_peer is not None:
            self._send(self._exchange_peer[0], ack)

    def _set_interval(self, ls: _LinkState, m: i.CommandIn, sender: tuple[int, int],
                      intent: SetMessageInterval) -> None:
        name = self._message_name(intent.message_id)
        rate = None if intent.interval_s is None else (0.0 if intent.interval_s == 0 else 1.0 / intent.interval_s)
        new = replan(self.streams, ls.name, name, rate, self.defaults[ls.name], self.tick_hz) if name else None
        if new is None:
            self._send(ls, command_ack(m, sender, MAV_RESULT_DENIED))
            return
        self.streams = new
        self._send(ls, command_ack(m, sender, MAV_RESULT_ACCEPTED))

    def _message_name(self, msg_id: int) -> str | None:
        ls_mod = self.links[0].endpoint.link.mod if self.links else None
        if ls_mod is None:
            return None
        cls = ls_mod.mavlink_map.get(msg_id)
        return None if cls is None else str(cls.msgname)

    def _can_send(self, msg_id: int) -> bool:
        """Whether MAV_CMD_REQUEST_MESSAGE for ``msg_id`` is answered with that message."""
        if msg_id in (MAVLINK_MSG_ID_AUTOPILOT_VERSION, MAVLINK_MSG_ID_HOME_POSITION):
            return True
        return self._message_name(msg_id) in STREAM_NAMES

    def _send_requested(self, ls: _LinkState, msg_id: int) -> None:
        if msg_id == MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            parts = [*_package_version(), 0, 0, 0]
            self._send(ls, o.autopilot_version((parts[0], parts[1], parts[2]), uid=self.opts.system_id))
        elif msg_id == MAVLINK_MSG_ID_HOME_POSITION:
            self._send(ls, o.home_position_from_frame(self.frame))
        else:
            name = self._message_name(msg_id)
            if name is not None:
                for msg in self._stream_messages(name, ls):
                    self._send(ls, msg)

    def _on_mission_protocol(self, ls: _LinkState, rx: i.Received, m: Any, sender: tuple[int, int]) -> None:
        """The mission protocol: waypoint missions to :attr:`mission`, fences (and the minimal answers for
        rally points) to :attr:`fence`; clearing every list (MAV_MISSION_TYPE_ALL) clears both, one answer."""
        if m.mission_type == MAV_MISSION_TYPE_MISSION:
            self._mission_link = ls
            outs = self.mission.handle(rx, rx.t_s)
        elif isinstance(m, i.MissionClearAllIn) and m.mission_type == MAV_MISSION_TYPE_ALL:
            outs = self.mission.handle_clear_all(sender)
            if isinstance(outs[0], o.MissionAckOut) and outs[0].result == MAV_MISSION_ACCEPTED:
                outs = self.fence.handle_clear_all(sender)
        else:
            self._fence_link = ls
            outs = self.fence.handle(rx, rx.t_s)
        for out in outs:
            self._send(ls, out)
        self._apply_fence_results()
        self._apply_mission_results()

    def _check_mission(self, plan: MissionPlan) -> tuple[int, str] | None:
        """The mission protocol's judge of an uploaded plan: its legs against the fence in force."""
        geo = self.cfg.geofence
        fence = self.loop.core_cfg.fence if geo.enabled else None
        return check_legs_against_fence(plan, fence, geo.margin_m, geo.altitude_ceiling_m)

    def _apply_mission_results(self) -> None:
        for res in self.mission.take_results():
            self.events.write({"t": self.t, "type": "mission_transfer", "upload": res.upload,
                               "result": res.result, "detail": res.detail})
            if res.result != MAV_MISSION_ACCEPTED:
                if res.upload and res.detail:  # the ground station shows why, naming the item
                    self._broadcast(o.StatusTextOut(o.MAV_SEVERITY_WARNING, f"Merlin: mission rejected: {res.detail}"))
                continue
            if not res.upload or res.plan is None:
                continue
            # flown by the trusted mission behaviour: the plan becomes the configuration's mission (uploads are
            # refused while armed, as every configuration change is, ICD 8.1)
            trusted = type(self.cfg.trusted).model_validate(
                {**self.cfg.trusted.model_dump(), **res.plan.trusted_update()})
            self._install_config(self.cfg.model_copy(update={"trusted": trusted}),
                                 {"source": "mission upload", "items": len(res.plan.items)})
            self._hand_mission_to_fixed_wing(res.plan)
            self._mission_reached, self._mission_current, self._mission_complete = -1, -1, False
            if self.loop.core.state.mission_index != 0 and not res.plan.empty:  # a new mission starts at its start
                self._cmd_seq += 1
                self.pending.commands.append(GcsCommand(GcsCommandKind.MISSION_CURRENT, param=0.0, seq=self._cmd_seq))
            self.events.write({"t": self.t, "type": "mission_applied", "items": len(res.plan.items),
                               "waypoints": len(res.plan.waypoints), "end": res.plan.end.value})

    def _on_mission_current(self, ls: _LinkState, t: float, seq: int, cmd: i.CommandIn | None,
                            sender: tuple[int, int]) -> None:
        """MISSION_SET_CURRENT (``cmd`` None) or MAV_CMD_DO_SET_MISSION_CURRENT: the item to fly next, as PX4
        takes it (in the mission the vehicle flies on to it at once; otherwise a later start or resume flies
        from it). The straight leg to it, which the upload's check never saw, is checked against the fence
        first; a refusal is answered DENIED (the command) and in STATUSTEXT naming the item."""
        plan = self.mission.plan
        why: str | None = None
        idx = 0
        if plan.empty:
            why = "no mission uploaded"
        elif seq == -1:  # "leave the current item": nothing to do
            if cmd is not None:
                self._send(ls, command_ack(cmd, sender, MAV_RESULT_ACCEPTED))
            return
        elif not 0 <= seq < len(plan.items):
            why = f"item {seq}: the mission has items 0 to {len(plan.items) - 1}"
        else:
            idx = waypoint_at_or_after(plan, seq)
            s = self.loop.state
            from_ne = (0.0, 0.0) if s.landed else (float(s.pos_ned_m[0]), float(s.pos_ned_m[1]))
            geo = self.cfg.geofence
            why = check_jump_against_fence(plan, idx, from_ne, self.loop.core_cfg.fence if geo.enabled else None,
                                           geo.margin_m)
        if why is not None:
            if cmd is not None:
                self._send(ls, command_ack(cmd, sender, MAV_RESULT_DENIED))
            else:  # the sender sees the item in force, unchanged
                self._send(ls, self._mission_current_message(self.decision))
            self._send(ls, o.StatusTextOut(o.MAV_SEVERITY_WARNING, f"Merlin: mission item not set: {why}"))
            self.events.write({"t": t, "type": "command_refused", "link": ls.name, "command": "MISSION_SET_CURRENT",
                               "detail": why})
            return
        self._cmd_seq += 1
        self.pending.commands.append(GcsCommand(GcsCommandKind.MISSION_CURRENT, param=float(idx), seq=self._cmd_seq))
        self._mission_jumps[self._cmd_seq] = idx
        if cmd is not None:
            self._cmd_waiting[self._cmd_seq] = (ls, cmd, sender)

    def _mission_jumped(self, idx: int) -> None:
        """The core took a MISSION_CURRENT: items skipped are not reported reached, items flown again are
        reported again, and MISSION_CURRENT goes out at once with the new item."""
        self._mission_reached = self.mission.plan.seq_of(idx) - 1
        self._mission_complete = False
        self._mission_current = -1
        stage, fm = self._fw_stage(), self._fw_mission()
        if stage is not None and fm is not None:  # the fixed wing's stage flies its own mission: moved there too
            flying = self.decision is not None and self.decision.behavior is Behavior.MISSION
            if idx >= len(stage.mission):
                fm.resume_index = 0
                if flying:
                    self._fw_mission_done = True
                    self._command_mission_end(self.t)
            else:
                fm.resume_index = idx
                if flying:
                    stage.mode_key = None  # re-entered from the new waypoint on the next tick

    def _fixed_wing_loiter(self, cmd: GcsCommand) -> tuple[GcsCommand, str | None]:
        """A fixed wing's GOTO or ORBIT is a loiter circle (merlin.autopilot.fixedwing_mission): an orbit's
        radius is never tighter than the stage's loiter radius (the core then checks the circle flown), and a
        GOTO's circle, which the core's check of the point alone does not see, is checked against the fence
        here. Returns the command to pass on and why it is refused (None: it is not)."""
        stage = self._fw_stage()
        if stage is None or cmd.kind not in (GcsCommandKind.GOTO, GcsCommandKind.ORBIT) or cmd.target_ned_m is None:
            return cmd, None
        low = stage.land_height_m  # the height its LAND loiter keeps from the terrain
        if -cmd.target_ned_m[2] < low:
            return cmd, (f"{cmd.kind.name} refused: the fixed wing's loiter at {-cmd.target_ned_m[2]:.1f} m above home"
                         f" is below {low:g} m, the lowest it loiters")
        if cmd.kind is GcsCommandKind.ORBIT:
            return replace(cmd, param=fixedwing_mission.orbit_radius_m(stage, cmd.param)), None
        fence = self.loop.core_cfg.fence if self.cfg.geofence.enabled else None
        why = fixedwing_mission.circle_block(fence, cmd.target_ned_m, stage.gp.loiter_radius_m)
        return cmd, (None if why is None else f"GOTO refused: {why}")

    def _mission_start_refused(self, cmd: GcsCommand) -> str | None:
        """Why a MISSION command must be refused now: the uploaded mission no longer fits the fence in force
        (a fence uploaded after it); None otherwise."""
        if cmd.kind is not GcsCommandKind.MISSION or self.mission.plan.empty:
            return None
        refused = self._check_mission(self.mission.plan)
        return None if refused is None else refused[1]

    def _hand_mission_to_fixed_wing(self, plan: MissionPlan) -> None:
        """A fixed wing flies MISSION in its own actuator stage (L1 legs at cruise airspeed, then a loiter at
        the last waypoint), whose waypoints are built once from the configuration: give it the new ones."""
        stage = getattr(self.loop, "stage", None)
        if stage is None or not hasattr(stage, "mission"):
            return
        from merlin.autopilot.fixedwing_guidance import Waypoint

        airspeed = stage.gp.rtl_airspeed_mps  # the stage's cruise airspeed
        stage.mission = tuple(Waypoint(n, e, -d, airspeed) for n, e, d in (w.pos_ned_m for w in plan.waypoints))
        if stage.fw_mission is not None:
            stage.fw_mission.resume_index = 0

    def _mission_progress(self, d: Decision) -> None:
        """MISSION_ITEM_REACHED for each item passed while flying the mission, and MISSION_CURRENT when the
        item being flown changes; the end item (RTL, LAND) is reported reached once the vehicle has landed
        and disarmed, as MAVSDK counts a mission finished by it."""
        plan = self.mission.plan
        if d.armed and not self._was_armed:  # a new flight flies the mission from its start (or the item set)
            start = self.loop.core.state.mission_index
            self._mission_reached = plan.seq_of(start) - 1 if start > 0 and not plan.empty else -1
            self._mission_complete = False
        self._was_armed = d.armed
        if plan.empty:
            return
        outs: list[o.OutMessage] = []
        idx = self._index_flown(d)
        if idx is not None:
            if idx >= len(plan.waypoints):
                self._mission_complete = True
                upto = plan.end_seq - 1 if plan.end_seq >= 0 else len(plan.items) - 1
            else:
                upto = plan.seq_of(idx) - 1
            outs += [o.MissionItemReachedOut(k) for k in range(self._mission_reached + 1, upto + 1)]
            self._mission_reached = max(self._mission_reached, upto)
        # the end item: once landed and disarmed (a fixed wing, which does not land here: once its RTL or LAND
        # loiter begins)
        ended = not d.armed or (self._fw_stage() is not None and d.behavior in (Behavior.RTL, Behavior.LAND))
        if (self._mission_complete and plan.end_seq > self._mission_reached and ended
                and plan.end is not MissionEnd.HOLD):
            outs.append(o.MissionItemReachedOut(plan.end_seq))
            self._mission_reached = plan.end_seq
        cur = self._mission_current_message(d)
        if cur.seq != self._mission_current:
            self._mission_current = cur.seq
            outs.append(cur)
        for msg in outs:
            self._broadcast(msg)

    def _fw_stage(self) -> Any:
        """The fixed wing's actuator stage (None for a multirotor)."""
        return getattr(self.loop, "stage", None) if self.mav_type == o.MAV_TYPE_FIXED_WING else None

    def _fw_mission(self) -> fixedwing_mission.FixedWingMission | None:
        stage = self._fw_stage()
        return None if stage is None else stage.fw_mission

    def _fixed_wing_tick(self, d: Decision) -> None:
        """After a fixed wing's tick: a new GOTO/ORBIT target re-enters the stage's behaviour (its loiter moves
        there); the mission's resume point follows the stage's L1 mission; flown to its end, the mission's end
        item (RTL, LAND) is commanded to the core, as the multirotor's core does itself."""
        stage, fm = self._fw_stage(), self._fw_mission()
        if stage is None or fm is None:
            return
        arb = self.loop.core.state.arbiter
        if arb.target_seq != self._fw_target_seq:
            self._fw_target_seq = arb.target_seq
            stage.mode_key = None
        if d.behavior is not Behavior.MISSION or d.authority is not Authority.TRUSTED or not stage.mission:
            return
        idx, finished = fixedwing_mission.progress(stage)
        if not finished:
            fm.resume_index, self._fw_mission_done = idx, False
        elif not self._fw_mission_done:
            self._fw_mission_done = True
            fm.resume_index = 0  # a later start flies it again from the first waypoint
            self._command_mission_end(d.t_s)

    def _command_mission_end(self, t: float) -> None:
        end = self.mission.plan.end
        kind = {MissionEnd.RTL: GcsCommandKind.RTL, MissionEnd.LAND: GcsCommandKind.LAND}.get(end)
        if kind is None:
            return
        self._cmd_seq += 1
        self.pending.commands.append(GcsCommand(kind, seq=self._cmd_seq))
        self.events.write({"t": t, "type": "fixed_wing_mission_end", "end": end.value})

    def _index_flown(self, d: Decision) -> int | None:
        """The waypoint being flown while the trusted MISSION flies (its length past the last), else None: the
        core's guidance's for a multirotor, the fixed-wing stage's own L1 mission for a fixed wing."""
        if d.behavior is not Behavior.MISSION:
            return None
        stage = self._fw_stage()
        if stage is not None:
            return fixedwing_mission.progress(stage)[0] if stage.mission else None
        g = self.loop.core.state.guidance
        return g.mission_index if g is not None and g.behavior is Behavior.MISSION else None

    def _mission_current_message(self, d: Decision | None) -> o.MissionCurrentOut:
        plan = self.mission.plan
        if plan.empty:
            return o.MissionCurrentOut(0, 0, o.MISSION_STATE_NO_MISSION, 2)
        flying = d is not None and d.behavior is Behavior.MISSION
        idx = self._index_flown(d) if flying and d is not None else None
        if idx is None:
            fm = self._fw_mission()
            idx = fm.resume_index if fm is not None else self.loop.core.state.mission_index
        if self._mission_complete:
            state, seq = o.MISSION_STATE_COMPLETE, plan.seq_of(len(plan.waypoints))
        else:
            state = o.MISSION_STATE_ACTIVE if flying else (
                o.MISSION_STATE_PAUSED if idx > 0 else o.MISSION_STATE_NOT_STARTED)
            seq = plan.seq_of(idx)
        return o.MissionCurrentOut(seq, len(plan.items), state, 1 if flying else 2)

    def _apply_fence_results(self) -> None:
        for res in self.fence.take_results():
            self.events.write({"t": self.t, "type": "fence_transfer", "upload": res.upload, "result": res.result,
                               "detail": res.detail})
            if res.upload and res.fence is not None and res.result == 0:
                geo = res.fence.apply_to(self.cfg.geofence)
                # uploads are refused while armed (ICD 8.1)
                self._install_config(self.cfg.model_copy(update={"geofence": geo}), {"source": "fence upload"})
                self.events.write({"t": self.t, "type": "fence_applied",
                                   "polygons": len(res.fence.polygons), "circles": len(res.fence.circles)})

    # -------------------------------------------------------------------------- configuration

    def _check_param(self, param_id: str, value: float) -> str | None:
        """The parameter protocol's validator: None if the configuration models accept the new value."""
        try:
            with_param(self.cfg, param_id, value)
        except ValueError as exc:
            return str(exc)
        return None

    def _on_param_write(self, w: ParamWrite, outs: list[o.OutMessage]) -> tuple[list[o.OutMessage], bool]:
        """Log a PARAM_SET with its outcome (ICD 8.2) and apply it if it changed a value. Returns the answer
        to send and whether the configuration changed."""
        self.events.write({"t": w.t_s, "type": "param_set", "result": w.result, "link": w.link,
                           "sender": list(w.sender), "param": w.param_id, "value": w.asked, "in_force": w.new,
                           "reason": w.reason or None})
        if w.result != "accepted" or w.new == w.old:
            return outs, False
        assert w.new is not None and w.old is not None
        try:
            # (validated a moment ago by _check_param on this same configuration: ~0.5 ms to build again)
            cfg = with_param(self.cfg, w.param_id, w.new)
            self._install_config(cfg, {"source": "PARAM_SET", "link": w.link, "sender": list(w.sender),
                                       "param": w.param_id, "old": w.old, "new": w.new})
        except Exception:  # a bug: the configuration in force stays, and the ground station is told so
            log.exception("applying %s = %g", w.param_id, w.new)
            self.events.write({"t": self.t, "type": "serve_error", "detail": f"applying PARAM_SET {w.param_id}"})
            self.params.replace(published_params(self.cfg))
            return [self.params.value_message(w.param_id),
                    o.StatusTextOut(o.MAV_SEVERITY_WARNING, f"Merlin: {w.param_id} not set (internal error)")], False
        return outs, True

    def _install_config(self, cfg: MerlinConfig, record: dict[str, Any]) -> None:
        """Make ``cfg`` the effective configuration: rebuild the trusted core from it, publish its envelope
        as parameters, record ``config_changed`` and rewrite ``effective_config.yaml``.

        Only ever called between ticks (from decoding what arrived), and only on the ground and disarmed:
        fence uploads are refused while armed, PARAM_SET while armed or airborne. The core's state carries
        over; if the number of enabled envelope limits changed, the core restarts its exceedance timers
        itself (``merlin.core.step.step``), which on the ground loses nothing that matters. Building the
        core's configuration takes ~40 ms (the fence grid): a few ticks start late, on the ground."""
        if self.loop.armed:
            raise RuntimeError("the configuration cannot change while armed")
        core_cfg = build_core_config(cfg, source=str(record.get("source", "<serve>")))
        self.loop.core = TrustedCore(core_cfg, self.loop.core.state)
        self.loop.core_cfg = core_cfg
        self.loop.cfg = cfg
        old_sha, self.cfg, self.cfg_sha256 = self.cfg_sha256, cfg, core_cfg.config_sha256
        self.limits = cfg.envelope.resolve(cfg.envelope.active_stage)
        self.params.replace(published_params(self.cfg))
        try:
            self._write_effective_config()
        except OSError as exc:  # the change is made and recorded below with its SHA-256 either way
            log.error("cannot write %s: %s", self.effective_config, exc)
            self.events.write({"t": self.t, "type": "serve_error", "detail": f"writing {EFFECTIVE_CONFIG}: {exc}"})
        self.events.write({"t": self.t, "type": "config_changed", **record, "old_sha256": old_sha,
                           "new_sha256": self.cfg_sha256, "effective_config": str(self.effective_config)})
        from merlin.link.params import envelope_params  # the ULog's parameters, as flight_meta writes them

        self.ulog.parameters_changed(self.t, envelope_params(self.limits), {
            "type": "config_changed", "old_sha256": old_sha, "new_sha256": self.cfg_sha256})

    def _write_effective_config(self) -> None:
        write_effective_config(self.effective_config, self.cfg.model_dump(mode="json"), [
            f"The effective configuration of merlin serve, SHA-256 {self.cfg_sha256}",
            f"(started from {self.opts.config_source}; every change is a config_changed record in events.jsonl).",
            "Key files under links: are relative to the directory of the configuration it started from.",
        ])

    # ---------------------------------------------------------------------------------- tick

    def _tick(self) -> None:
        t = self.t
        state = self.loop.sense()
        prev = self.decision
        if self.loop.core_due:
            d = self._core_tick(t, state)
        else:
            # the core's period spans several ticks and this is not its tick: the actuator stage flies its last
            # decision; what arrived meanwhile waits in self.pending for the core's next tick, as merlin sim's
            # runner holds its commands (nothing lost, nothing decided twice, no event reported twice)
            d = self.loop.act(None)
        self.decision = d
        self._fixed_wing_tick(d)
        self.ulog.record(t, state, d, self.sp, self.loop)
        if d is not prev:
            for e in d.events:
                self._on_event(e, d)
        changed = prev is None or (prev.authority, prev.behavior, prev.armed) != (d.authority, d.behavior, d.armed)
        if changed:
            for ls in self.links:
                self._send(ls, self._heartbeat(ls, d))
            self._broadcast(self._authority_status(d))
        if self._revoke_repeats and self._revoke_repeats[0][0] <= t:
            due = [m for (tt, m) in self._revoke_repeats if tt <= t]
            self._revoke_repeats = [(tt, m) for (tt, m) in self._revoke_repeats if tt > t]
            for msg in due:
                self._broadcast(msg)
        self.fence.accept_uploads = not d.armed
        # PARAM_SET may change the configuration only on the ground and disarmed (ICD 8.2); what arrives until
        # the next tick is judged by this tick's decision and state
        self.params.read_only = "while armed" if d.armed else (None if state.landed else "while airborne")
        if self.fence.busy:
            outs = self.fence.tick(t)
            if outs and self._fence_link is not None:
                for out in outs:
                    self._send(self._fence_link, out)
            self._apply_fence_results()
        self.mission.accept_uploads = not d.armed
        if self.mission.busy:
            outs = self.mission.tick(t)
            if outs and self._mission_link is not None:
                for out in outs:
                    self._send(self._mission_link, out)
            self._apply_mission_results()
        self._mission_progress(d)
        k = self.loop.k
        for s in self.streams:
            if k % s.period_ticks == s.phase_ticks:
                ls = self._link(s.link)
                if ls is not None:
                    msgs = self._stream_messages(s.name, ls)
                    if s.name == "MERLIN_ENVELOPE_STATUS":
                        ls.bulk.extend(msgs)
                    else:
                        for msg in msgs:
                            self._send(ls, msg)
        for ls in self.links:
            for _ in range(min(BULK_PER_TICK, len(ls.bulk))):
                self._send(ls, ls.bulk.popleft())

    def _core_tick(self, t: float, state: VehicleState) -> Decision:
        """The core's tick: what arrived since its last tick becomes its inputs, built as merlin sim builds them
        (merlin.pipeline.InputBuilder), with the vehicle's redundancy report; returns its decision."""
        p = self.pending
        self.pending = _Pending()
        self._advance_held_request(t, p.requests)
        self._advance_requeued(t, p.requests)
        self._advance_takeoff(t, p)
        sp_arrival_ns = 0
        if p.setpoint is not None:
            sp_t, m, sp_arrival_ns = p.setpoint
            self.stats.coalesced += p.coalesced
            yaw = state.att_rpy_rad[2]
            if isinstance(m, i.SetpointIn):
                self.sp = m.to_setpoint(state.pos_ned_m, yaw)
            elif isinstance(m, i.GlobalSetpointIn):
                self.sp = m.to_setpoint(self.frame, yaw)
            else:
                self.sp = m.to_setpoint()
            self.sp_t = sp_t
        b = self.inputs
        b.controller_heartbeat(self.hb_t)
        b.setpoint(self.sp, self.sp_t)
        b.request(tuple(p.requests))
        b.gcs_heartbeat(self.gcs_t)
        b.rc_frame(self.rc_t)
        b.operator(self.op)
        inputs = b.build(state, tuple(p.commands), self.loop.redundancy_report(t))
        d = self.loop.act(inputs)
        if sp_arrival_ns:
            self.stats.record_setpoint_latency(time.monotonic_ns() - sp_arrival_ns)
        return d

    def _link(self, name: str) -> _LinkState | None:
        for ls in self.links:
            if ls.name == name:
                return ls
        return None

    def _authority_status(self, d: Decision) -> o.AuthorityStatusOut:
        t = self.t
        hc = self.cfg.handover
        cooldown = 0.0
        if self._last_revoke_t is not None:
            cooldown = max(0.0, hc.cooldown_s - (t - self._last_revoke_t))
        wd = self.cfg.watchdogs
        hb_ok = self.hb_t is not None and t - self.hb_t <= wd.controller_heartbeat.timeout_s
        sp_fresh = self.sp_t is not None and t - self.sp_t <= wd.setpoint_stale.timeout_s
        ctl = self._controller_link()
        signing = bool(ctl and ctl.endpoint.link.signing_required_for)
        return o.authority_status_from_decision(
            d, self._boot_ms(), active_grant_seq=self._grant_seq_active,
            max_revocations=hc.max_revocations_per_flight, cooldown_remaining_s=cooldown,
            last_reason=self._last_reason, landed=self.loop.state.landed, controller_heartbeat_ok=hb_ok,
            setpoint_fresh=sp_fresh, signing_required=signing)

    def _stream_messages(self, name: str, ls: _LinkState) -> list[o.OutMessage]:
        s = self.loop.state
        ms = self._boot_ms()
        d = self.decision
        if name == "HEARTBEAT":
            return [self._heartbeat(ls, d)] if d is not None else []
        if name == "ATTITUDE":
            return [o.attitude_from_state(s, ms)]
        if name == "LOCAL_POSITION_NED":
            return [o.local_position_from_state(s, ms)]
        if name == "GLOBAL_POSITION_INT":
            return [o.global_position_from_state(s, self.frame, ms)]
        if name == "GPS_RAW_INT":
            lat, lon, alt = self.frame.to_geodetic(*s.pos_ned_m)
            vn, ve, _ = s.vel_ned_mps
            return [o.GpsRawIntOut(int(self.loop.t * 1e6), 3, lat, lon, alt, s.pos_sigma_h_m, s.pos_sigma_v_m,
                                   math.hypot(vn, ve), math.atan2(ve, vn) % (2 * math.pi), 12)]
        if name == "VFR_HUD":
            return [o.vfr_hud_from_state(s, self.frame, _throttle(self.loop.motors))]
        if name == "SYS_STATUS":
            # sensor bits as PX4 reports them, so that QGroundControl and MAVSDK's health checks pass
            # (MAVSDK reads global-position health from the GPS bit and "armable" from PREARM_CHECK)
            health = SENSORS_PRESENT if s.nav_mode is NavMode.GPS else SENSORS_PRESENT & ~SENSOR_GPS
            return [replace(o.sys_status_from_state(s), sensors_present=SENSORS_PRESENT,
                            sensors_enabled=SENSORS_PRESENT, sensors_health=health)]
        if name == "EXTENDED_SYS_STATE":
            return [o.extended_sys_state_from_state(s)]
        if name == "HOME_POSITION":
            return [o.home_position_from_frame(self.frame)]
        if name == "MISSION_CURRENT":
            return [self._mission_current_message(d)]
        if name == "MERLIN_AUTHORITY_STATUS":
            return [self._authority_status(d)] if d is not None else []
        if name == "MERLIN_ENVELOPE_STATUS":
            elapsed: dict[str, float] = {}
            if d is not None:
                for mon in d.monitors:
                    if mon.name == MonitorId.ENVELOPE:
                        elapsed = dict(mon.detail)
            return list(o.envelope_status_from(ms, s, self.limits, self.cfg.envelope.active_stage, elapsed))
        return []

    def _on_event(self, e: Event, d: Decision) -> None:
        self.events.write(e.to_dict())
        ms = self._boot_ms()
        for out in self.bridge.on_event(e):
            ctl = self._exchange_peer[0] if self._exchange_peer else self._controller_link()
            if ctl is not None:
                self._send(ctl, out)
        peer_ls, peer = self._exchange_peer if self._exchange_peer else (self._controller_link(), (0, 0))
        hc = self.cfg.handover
        if e.kind is EventKind.GRANTED:
            req_id = self._take_request_id()
            auth = Authority.SHADOW if e.to is Authority.SHADOW else Authority.EXPERIMENTAL
            self._broadcast(o.grant_from_event(e, ms, peer, req_id, auth, hc.ack_timeout_s, hc.blend_window_s))
        elif e.kind is EventKind.DENIED:
            if self.takeoff.phase.value == "requested" and e.to is not None:
                self._takeoff_denied(e)
            elif e.to is not None and self._standard_request is not None:
                if e.seq != 0:
                    self._switch_denied(e)
                else:  # refused when asked: its sender hears why (the bridge's COMMAND_ACK)
                    self._standard_request, self._requeued = None, False
            req_id = self._take_request_id() if e.seq == 0 else 0
            retry = hc.cooldown_s - (self.t - self._last_revoke_t) if (
                e.reason.code is ReasonCode.COOLDOWN and self._last_revoke_t is not None) else 0.0
            self._broadcast(o.deny_from_event(e, ms, peer, req_id, max(0.0, retry)))
        elif e.kind is EventKind.ACKNOWLEDGED:
            self._grant_seq_active = e.seq
        elif e.kind is EventKind.AUTHORITY and e.to is Authority.EXPERIMENTAL:
            self._standard_request, self._requeued = None, False
        elif e.kind is EventKind.REVOKED or e.kind is EventKind.RELEASED:
            released = e.kind is EventKind.RELEASED or e.reason.code is ReasonCode.RELEASED
            cooldown = 0.0 if released else hc.cooldown_s
            if not released:
                self._last_revoke_t = self.t
            rv = o.revoke_from_event(e, ms, peer, self._grant_seq_active or e.seq, cooldown, d.revocations)
            self._broadcast(rv)
            if not released:
                self._revoke_repeats += [(self.t + dt, rv) for dt in REVOKE_REPEATS_S]
        elif e.kind is EventKind.COMMAND_ACK:
            jump = self._mission_jumps.pop(e.seq, None)
            if jump is not None and e.accepted:
                self._mission_jumped(jump)
            waiting = self._cmd_waiting.pop(e.seq, None)
            if waiting is not None:
                ls, cmd, sender = waiting
                if (not e.accepted and ls.role is LinkRole.CONTROLLER and e.command is GcsCommandKind.HOLD
                        and e.reason.code in (ReasonCode.LANDED, ReasonCode.NOT_ARMED) and self.loop.state.landed):
                    # the same HOLD on the ground as above, when the touchdown came between its arrival and the
                    # core's tick (the MAVSDK offboard example whose last setpoint is on the ground stops offboard
                    # as it touches down); disarmed on the ground too, as PX4
                    self._hold_on_ground(ls, cmd, sender, self.t)
                else:
                    self._send(ls, command_ack(cmd, sender,
                                               MAV_RESULT_ACCEPTED if e.accepted else MAV_RESULT_DENIED))
                    if not e.accepted and e.command is not None:  # why, for the sender's message panel
                        self._send(ls, o.StatusTextOut(o.MAV_SEVERITY_WARNING,
                                                       f"Merlin: {e.command.name} refused: {e.reason.describe()}"))
        if e.reason.code is not ReasonCode.NONE and e.kind in (EventKind.REVOKED, EventKind.DENIED):
            self._last_reason = e.reason.code
        text = o.statustext_for_event(e)
        if text is not None:
            self._broadcast(text)
        _ = peer_ls

    def _take_request_id(self) -> int:
        if not self._request_ids:
            return 0
        ls, rid, sender = self._request_ids.pop(0)
        self._exchange_peer = (ls, sender)
        return rid

    # ---------------------------------------------------------------------------------- loop

    def _fds(self) -> dict[int, _LinkState]:
        out: dict[int, _LinkState] = {}
        for ls in self.links:
            tr = ls.endpoint.transport
            fd = tr.sock.fileno() if hasattr(tr, "sock") else tr.port.fileno()
            out[fd] = ls
        return out

    def _drain(self, ls: _LinkState, until_ns: int | None = None, before_ns: int | None = None) -> int:
        """Read what the link's socket holds (at most MAX_DATAGRAMS_PER_READ more than the backlog) and
        decode and handle it in arrival order until ``until_ns`` (monotonic; None: all of it), only what
        arrived before ``before_ns`` (None: all of it). Returns how many datagrams were handled; the rest
        stay in ``ls.backlog`` for the next call.

        ``before_ns`` is how a tick run late, catching up after the process stalled, gets only what had
        arrived by its time in the schedule (Server.run): the datagrams that waited in the socket during
        the stall are spread over the catch-up ticks by their kernel receive times, as ticks on time would
        have taken them. Handled all at the first of those ticks, a controller that kept streaming would be
        seen silent for the whole stall in the core's clock, and revoked for the vehicle's own delay
        (tests/serve/test_scheduler.py, the stalled serve)."""
        ep = ls.endpoint
        t = self.t
        if len(ls.backlog) < MAX_DATAGRAMS_PER_READ:
            batch = read_stamped(ep.transport)
            if batch:
                ls.backlog.extend(batch)
        if ls.role is LinkRole.CONTROLLER and len(ls.backlog) > 1:
            self._coalesce(ls.backlog, before_ns)
        n = 0
        while ls.backlog and (until_ns is None or time.monotonic_ns() < until_ns):
            if before_ns is not None and ls.backlog[0][2] >= before_ns:
                break
            data, addr, self._read_ns = ls.backlog.popleft()
            n += 1
            rxs = ep.link.receive(data, t, time.time(), final=ep.transport.datagram)
            # the same rule as MavlinkEndpoint.poll: follow a peer only after an accepted (signed) message
            if rxs and addr is not None and (not ep.link.security.required or any(r.signed for r in rxs)):
                ep.transport.remote = addr
            for rx in rxs:
                if isinstance(rx.msg, i.SetupSigningIn) and ep.key_file is not None:
                    write_key_file(ep.key_file, rx.msg.secret_key)
                try:
                    self._on_received(ls, rx)
                except Exception:  # a bug handling one message must not stop the vehicle: logged, dropped
                    log.exception("handling %s from %d/%d", type(rx.msg).__name__, rx.system_id, rx.component_id)
                    self.events.write({"t": self.t, "type": "serve_error",
                                       "detail": f"handling {type(rx.msg).__name__}"})
        return n

    def _coalesce(self, backlog: deque[tuple[bytes, Any, int]], before_ns: int | None = None) -> None:
        """Drop from ``backlog``, before decoding, setpoint datagrams superseded by a later one from the
        same sender: only the latest setpoint before a tick matters (icd/ICD.md section 7), and decoding
        costs ~0.1 ms a frame. A superseded datagram is still written to the tlog and counted. Only
        datagrams holding exactly one MAVLink 2 setpoint frame are candidates; anything else is decoded as
        usual, in order. A setpoint is superseded only by a later one with nothing else between them: a
        command sent after a setpoint (OFFBOARD right after the first one, as MAVSDK's examples do) is
        still handled after a setpoint, as it was sent. Only datagrams that arrived before ``before_ns``
        (None: all) take part: a later one belongs to a later tick (:meth:`_drain`), and must not take the
        place of one that a tick before it handles."""
        items = backlog if before_ns is None else itertools.takewhile(lambda item: item[2] < before_ns, backlog)
        keys = [_lone_setpoint_sender(item[0]) for item in items]
        superseded: set[int] = set()
        later: set[tuple[int, int]] = set()  # senders with a later setpoint in this run of setpoints
        for k in range(len(keys) - 1, -1, -1):
            key = keys[k]
            if key is None:
                later = set()
            elif key in later:
                superseded.add(k)
            else:
                later.add(key)
        if not superseded:
            return
        kept: list[tuple[bytes, Any, int]] = []
        now = time.time()
        for k, item in enumerate(backlog):
            if k in superseded:
                self.tlog.write(item[0], now)
                self.stats.coalesced += 1
                continue
            kept.append(item)
        backlog.clear()
        backlog.extend(kept)

    def stop(self) -> None:
        self._stop = True

    def _collect_garbage(self) -> None:
        """Python's cycle collector, by hand right after a tick (automatic collection is off while serving).

        A collection costs time in proportion to the objects it traverses. Nearly everything a tick
        allocates is freed by reference counting at once; what is still alive at a collection is either
        small (a few dozen objects) or a bulk of long-lived data, e.g. the simulator's blocks of 1024
        pre-drawn noise rows (one Python list per row, ``sims/sensors.py``), which traversing costs ~5 ms,
        more than a tick's slack. So: fewer than GC_BULK_OBJECTS new objects are collected (youngest
        generation, and the middle one every GC_MIDDLE_EVERY-th time); more are frozen (moved, in constant
        time, to the generation that is never scanned; they are still freed by reference counting when
        dropped). Cyclic garbage that happens to be among them is not reclaimed: ``gc_frozen`` counts
        what was frozen, ``gc_unreachable`` what the collections found, so a leak would show in the
        ``serve_stop`` record."""
        g0 = time.monotonic_ns()
        k = self.loop.k
        young = gc.get_count()[0]
        if young >= GC_BULK_OBJECTS or k == GC_EVERY_TICKS:
            # (also once after the first ticks: what they created once, lazy imports and caches, joins the
            # start-up objects that are never scanned again)
            gc.freeze()
            self.stats.gc_frozen += young
            gen = -1
        else:
            gen = 1 if k % (GC_EVERY_TICKS * GC_MIDDLE_EVERY) == 0 else 0
            self.stats.gc_unreachable += gc.collect(gen)
        self.stats.record_gc(time.monotonic_ns() - g0, k, gen)

    def _wait_until(self, deadline: int, fd_list: list[int], fds: dict[int, _LinkState],
                    period_ns: int | None = None) -> None:
        """Return at ``deadline`` (monotonic ns), decoding what arrives meanwhile but never within
        DRAIN_GUARD_NS of it; the last SPIN_NS are spun, below the sleep's timer slack. What is decoded is
        for the tick due at ``deadline``: what arrived before the one after it (``period_ns`` later), which
        while waiting is everything."""
        period_ns = self.stats.period_ns if period_ns is None else period_ns
        while True:
            left = deadline - time.monotonic_ns()
            if left <= DRAIN_GUARD_NS:
                break
            if any(ls.backlog for ls in fds.values()):
                ready = [fd for fd, ls in fds.items() if ls.backlog]
            else:
                ready, _, _ = select.select(fd_list, [], [], (left - DRAIN_GUARD_NS) / 1e9)
            for fd in ready:
                self._drain(fds[fd], deadline - DRAIN_GUARD_NS, deadline + period_ns)
        left = deadline - time.monotonic_ns()
        if left > SPIN_NS:
            time.sleep((left - SPIN_NS) / 1e9)
        while time.monotonic_ns() < deadline:
            pass

    def _sync_files(self) -> None:
        while not self._stop:
            time.sleep(FSYNC_INTERVAL_S)
            for fd in (getattr(self.tlog, "_fd", None), self.events.fileno()):
                if fd is not None and fd >= 0:
                    with contextlib.suppress(OSError):
                        os.fsync(fd)

    def run(self) -> dict[str, Any]:
        """Serve until the duration elapses or :meth:`stop`; returns the timing and link statistics."""
        opts = self.opts
        self.events.write({"t": 0.0, "type": "serve_start", "rate_hz": opts.rate_hz,
                           "core_dt_s": self.loop.core_every * self.dt, "nav_dt_s": self.loop.tick.nav_every * self.dt,
                           "speedup": opts.speedup,
                           "estimator": self.estimator, "estimator_note": self.estimator_note,
                           "config": opts.config_source, "config_sha256": self.cfg_sha256,
                           "effective_config": str(self.effective_config),
                           "params": "locked" if self.params_locked else "writable on the ground (gcs link)",
                           "links": {
                               ls.name: {"local": getattr(ls.endpoint.transport, "local_address", None),
                                         "remote": ls.endpoint.remote, "security": self._security(ls)}
                               for ls in self.links}})
        # started first, so it keeps the normal scheduler (a thread inherits its creator's policy)
        self._syncer.start()
        if opts.realtime_priority > 0:
            # the seed FCU thesis runs its single RateGenerator SCHED_FIFO (notes/seed_004_notes.md section 2)
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(opts.realtime_priority))
                self.events.write({"t": 0.0, "type": "realtime", "policy": "SCHED_FIFO",
                                   "priority": opts.realtime_priority})
            except (AttributeError, OSError) as exc:
                log.warning("cannot switch to SCHED_FIFO (%s); running with the normal scheduler", exc)
                self.events.write({"t": 0.0, "type": "realtime", "policy": "normal", "detail": str(exc)})
            self.events.write({"t": 0.0, "type": "memory_lock", **_lock_memory()})
        for ls in self.links:
            if hasattr(ls.endpoint.transport, "max_datagrams_per_read"):
                ls.endpoint.transport.max_datagrams_per_read = MAX_DATAGRAMS_PER_READ
        fds = self._fds()
        fd_list = list(fds)
        links = list(fds.values())
        period_ns = self.stats.period_ns
        n_ticks = None if opts.duration_s is None else round(opts.duration_s / self.dt)
        if opts.tune_gc:
            gc.collect()
            gc.freeze()  # start-up objects never need scanning again
            gc.disable()  # collections run by hand between ticks, where the slack is (below)
        t0 = time.monotonic_ns()
        deadline = t0
        prev_start: int | None = None
        usage = _thread_usage()
        prev_usage = usage() if usage else None
        try:
            while not self._stop and (n_ticks is None or self.loop.k < n_ticks):
                self._wait_until(deadline, fd_list, fds, period_ns)
                now = time.monotonic_ns()
                late = now - deadline
                if late > RESYNC_TICKS * period_ns:
                    self.stats.resyncs += 1
                    deadline = now
                    late = 0
                start = now
                budget_end = start + TICK_DRAIN_BUDGET_NS
                # what arrived since the last wake-up, time-bounded, and before the next tick was due: on
                # time that is all of it; catching up, what this tick would have seen on time (_drain)
                for ls in links:
                    self._drain(ls, budget_end, deadline + period_ns)
                self._tick()
                work = time.monotonic_ns() - start
                ctx = None
                if usage is not None and prev_usage is not None:
                    # one getrusage(2) per tick (about a microsecond): what the guest kernel saw of this
                    # thread since the previous tick started, to explain a missed tick (records.TickStats)
                    u = usage()
                    ctx = (u[0] - prev_usage[0], u[1] - prev_usage[1], u[2] - prev_usage[2])
                    prev_usage = u
                self.stats.record(late, start, prev_start, work, self.loop.k, ctx)
                prev_start = start
                if self.on_tick is not None:
                    self.on_tick(self)
                if opts.tune_gc and self.loop.k % GC_EVERY_TICKS == 0:
                    self._collect_garbage()
                deadline += period_ns
        finally:
            if opts.tune_gc:
                gc.enable()
            summary = self.close()
        return summary

    def _security(self, ls: _LinkState) -> dict[str, object]:
        o_ = self.opts
        if ls.role is LinkRole.CONTROLLER:
            return describe(LinkSetup(o_.controller_policy, o_.controller_key_file))
        return describe(LinkSetup(o_.gcs_policy, o_.gcs_key_file))

    def close(self) -> dict[str, Any]:
        self._stop = True
        links = {}
        for ls in self.links:
            st = ls.endpoint.stats()
            links[ls.name] = {"frames_in": st.frames_in, "frames_out": st.frames_out, "accepted": st.accepted,
                              "ignored": st.ignored, "not_for_us": st.not_for_us,
                              "frame_errors": dict(st.frame_errors), "rejected": dict(st.rejected)}
            for rec in ls.endpoint.link.recent_rejections()[-20:]:
                self.events.write({"t": rec.t_s, "type": "link_rejection", "link": rec.link, "sender":
                                   [rec.system_id, rec.component_id], "message": rec.msg_name,
                                   "reason": rec.reason.value, "detail": rec.detail})
        timing = {**self.stats.summary(), "tlog_write_max_ms": self.tlog.max_write_ns / 1e6,
                  "tlog_writes_over_1ms": self.tlog.slow_writes}
        summary = {"estimator": self.estimator, "timing": timing, "links": links,
                   "final": {"t_s": self.t, "authority": self.decision.authority.name if self.decision else None,
                             "armed": bool(self.decision.armed) if self.decision else False}}
        self.events.write({"t": self.t, "type": "serve_stop", **summary})
        for ls in self.links:
            ls.endpoint.close()
        self.tlog.close()
        self.ulog.close()
        self.events.close()
        return summary


_SETPOINT_IDS = frozenset({82, 84, 86})  # SET_ATTITUDE_TARGET, SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT


def _lone_setpoint_sender(data: bytes) -> tuple[int, int] | None:
    """(system, component) if ``data`` is exactly one MAVLink 2 setpoint frame, else None (header only:
    the frame is not trusted for anything but the choice of what to decode)."""
    if len(data) < 12 or data[0] != 0xFD:
        return None
    size = 12 + data[1] + (13 if data[2] & 1 else 0)
    if len(data) != size:
        return None
    if data[7] | data[8] << 8 | data[9] << 16 not in _SETPOINT_IDS:
        return None
    return (data[5], data[6])


def _thread_usage() -> Callable[[], tuple[int, int, int]] | None:
    """(involuntary context switches, minor faults, major faults) of the calling thread, or None where
    the platform has no per-thread usage (RUSAGE_THREAD is Linux)."""
    try:
        import resource

        who = resource.RUSAGE_THREAD
    except (ImportError, AttributeError):
        return None

    def read() -> tuple[int, int, int]:
        r = resource.getrusage(who)
        return (r.ru_nivcsw, r.ru_minflt, r.ru_majflt)

    return read


def _lock_memory() -> dict[str, object]:
    """Lock the process's pages in RAM (mlockall(MCL_CURRENT | MCL_FUTURE)), as real-time flight software
    on Linux does, so the scheduler thread never waits for a page to come back from disk or from the
    kernel's reclaim. Only where locking cannot later make an allocation fail: the lock limit is unlimited
    (RLIMIT_MEMLOCK, or root's CAP_IPC_LOCK); otherwise nothing is locked and the record says why."""
    try:
        import ctypes
        import ctypes.util
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
        if soft != resource.RLIM_INFINITY and os.geteuid() != 0:
            return {"locked": False, "detail": f"RLIMIT_MEMLOCK is {soft} bytes, not unlimited"}
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        mcl_current, mcl_future = 1, 2  # <sys/mman.h> on Linux
        if libc.mlockall(mcl_current | mcl_future) != 0:
            err = ctypes.get_errno()
            return {"locked": False, "detail": f"mlockall: {os.strerror(err)}"}
        return {"locked": True, "detail": "mlockall(MCL_CURRENT | MCL_FUTURE)"}
    except (ImportError, AttributeError, OSError) as exc:  # not Linux, or no C library to call
        return {"locked": False, "detail": str(exc)}


def _package_version() -> list[int]:
    from importlib.metadata import PackageNotFoundError, version

    try:
        v = version("merlin-autopilot")
    except PackageNotFoundError:
        return []
    return [int(x) for x in v.split(".")[:3] if x.isdigit()]


def _throttle(motors: Any) -> float:
    try:
        vals = [float(x) for x in motors]
    except TypeError:
        return 0.0
    return sum(vals) / len(vals) if vals else 0.0


def install_signal_handlers(server: Server) -> None:
    def handler(_sig: int, _frame: object) -> None:
        server.stop()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)


__all__ = ["ServeOptions", "Server", "UdpLinkSpec", "install_signal_handlers"]
