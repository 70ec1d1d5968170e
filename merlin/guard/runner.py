"""The guard's loop: the imperative shell around the trusted core on a companion computer.

One thread. Frames are routed as they arrive (so a controller's setpoint reaches the autopilot within
the time it takes to read, classify and write it, not at the next tick); the core runs at
``guard.rate_hz`` on the autopilot's telemetry and decides authority; its decision opens or closes the
gate and, after a revocation, its trusted command is streamed to the autopilot in the dialect
(:mod:`merlin.guard.trusted`).

Start-up (:meth:`Guard.start`), before anything from the controller reaches the autopilot:

1. wait for the autopilot's HEARTBEAT and recognise the dialect and vehicle
   (:func:`merlin.guard.dialects.detect`);
2. read the failsafe parameters and refuse to start if the autopilot would not catch a dead guard
   (:mod:`merlin.guard.failsafe_params`): :class:`GuardRefused` carries every refusal;
3. request the telemetry streams (MAV_CMD_SET_MESSAGE_INTERVAL).

Until the check has passed nothing is routed: the controller and the ground station do not see the
autopilot (a MAVSDK program waits for its HEARTBEAT before it sends), and whatever they sent blind in
the meantime is discarded once routing begins, not delivered late: a command the sender has retried or
given up on by then must not be executed (MAVSDK-Python's examples through the guard: queued
REQUEST_MESSAGE retries answered twice).

Authority follows the ICD's standard flow for controllers that do not speak Merlin's dialect: the
controller's request for the dialect's offboard mode (PX4 OFFBOARD, ArduPilot GUIDED) is the REQUEST; the
guard holds the mode command until the core decides; on a grant the guard acknowledges the grant for the
controller (the mode command itself is the controller's intent, and its setpoints already stream), and
once the core has handed authority over (its check of the first setpoint against the vehicle passed) it
forwards the command, so the autopilot's own COMMAND_ACK answers the controller; on a denial the guard
answers COMMAND_ACK DENIED and a STATUSTEXT with the reason. On a revocation the guard stops passing the
controller's setpoints and streams the trusted command instead; the controller sees the autopilot's
HEARTBEAT with the mode of Merlin's behaviour (PX4 AUTO.LOITER/AUTO.RTL/AUTO.LAND, Copter BRAKE/RTL/LAND)
in place of OFFBOARD/GUIDED, so standard tools see the revocation as the mode change they know.

Logs in ``out_dir`` (pymavlink's tlog format): ``guard.tlog``, every frame received on every link once
and every frame the guard originates (forwarded copies are not repeated); ``autopilot.tlog``, the
autopilot's frames alone, which ``merlin replay`` reads as a flight log; ``events.jsonl``, the core's
events and the guard's own (start check, requests, denials, revocations, the braking or turn measured, stop).
A frame's tlog records are written once it has been handled (a setpoint is forwarded before any file is
written), and the controller's link is read again between the core's step and the rest of a tick: a setpoint
that arrives during a tick waits for the core's decision, not for the tick's logs and trusted stream.
"""

from __future__ import annotations

import json
import logging
import math
import os
import select
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from merlin.config.models import MerlinConfig
from merlin.config.runtime import build_core_config
from merlin.core.geofence import STANDARD_GRAVITY_MPS2
from merlin.core.step import TrustedCore
from merlin.core.types import (
    Authority,
    AuthorityRequest,
    Decision,
    EventKind,
    GcsCommand,
    GcsCommandKind,
    MonitorId,
    NavMode,
    RequestKind,
    Setpoint,
    SetpointKind,
)
from merlin.geodesy import LocalFrame
from merlin.guard import inputs_log
from merlin.guard.config import GuardConfig
from merlin.guard.dialects import Autopilot, Dialect, ModeTable, VehicleClass, detect, mode_table
from merlin.guard.endpoints import EndpointSpec, open_transport
from merlin.guard.failsafe_params import ParamReader, Refusal, check, requirements
from merlin.guard.fixedwing_targets import FixedWingStream, GuidedTarget
from merlin.guard.gate import GateContext, Route, classify
from merlin.guard.intent import ControllerIntent, Refused
from merlin.guard.response import BrakeMeasurement, BrakeMeter, TurnMeasurement, TurnMeter
from merlin.guard.telemetry import TelemetryState, stream_requests
from merlin.guard.trusted import TrustedOutput, trusted_output
from merlin.link import autopilot_wire as w
from merlin.link.frames import Frame
from merlin.link.signing import SignatureCheck, SigningState
from merlin.link.tlog import TlogWriter
from merlin.pipeline import InputBuilder

log = logging.getLogger("merlin.guard")
EFFECTIVE_CONFIG = "effective_config.yaml"


def write_effective_config(out_dir: Path, cfg: MerlinConfig, gcfg: GuardConfig) -> None:
    """What the session ran with, beside its logs: the Merlin configuration and the guard: section."""
    import yaml

    data = cfg.model_dump(mode="json")
    data["guard"] = gcfg.model_dump(mode="json")
    (out_dir / EFFECTIVE_CONFIG).write_text(yaml.safe_dump(data, sort_keys=False))
HEARTBEAT_PERIOD_S = 1.0
STATUSTEXT_REPEAT_S = 1.0
SWITCH_TIMEOUT_S = 2.0
GUIDED_TURN_PERIOD_S = 0.2  # a fixed wing's turn point, moved with the course, sent this often (ArduPlane)
GUIDED_REPEAT_S = 1.0  # an unchanged guided point is sent again this often (a lost command is repeated)
GUIDED_MOVE_M = 5.0  # a guided point that moved more than this is sent at once
HOLD_MARGIN_S = 0.05  # a held request reaches the core this long after the liveness rule is met (one tick+)
IN_PROGRESS_INTERVAL_S = 0.5  # as merlin serve: MAVSDK waits 1.5 s after each IN_PROGRESS
MAV_RESULT_IN_PROGRESS = 5  # after a grant, the autopilot must show its offboard mode within this  # one STATUSTEXT per denial reason per second at most


class GuardRefused(RuntimeError):
    def __init__(self, autopilot: Autopilot | None, refusals: list[Refusal], detail: str = "") -> None:
        self.autopilot = autopilot
        self.refusals = refusals
        lines = [r.text() for r in refusals] or [detail]
        who = autopilot.describe() if autopilot else "the autopilot"
        super().__init__(f"merlin guard refuses to start on {who}:\n  " + "\n  ".join(lines))


@dataclass
class _Link:
    name: str
    transport: Any
    splitter: Any = field(default_factory=w.frame_splitter)
    frames_in: int = 0
    frames_out: int = 0
    #: MAVLink 2 signing on this link: inbound frames must verify against the key, outbound ones are signed
    verify: SigningState | None = None
    signer: w.LinkSigner | None = None

    def fileno(self) -> int:
        t = self.transport
        if hasattr(t, "sock") and t.sock is not None and hasattr(t.sock, "fileno"):
            return int(t.sock.fileno())
        if hasattr(t, "fileno"):
            return int(t.fileno())
        if hasattr(t, "port"):
            return int(t.port.fileno())
        return -1


@dataclass
class _Held:
    """An offboard-mode request held until the core decides."""

    raw: bytes
    command: int | None  # the MAV_CMD to answer (None: SET_MODE, which has no COMMAND_ACK)
    sender: tuple[int, int]
    t_s: float
    # held by the guard (IN_PROGRESS sent) until the controller's liveness is established; None: with the core
    release_t: float | None = None
    next_progress_t: float = 0.0


class Guard:
    def __init__(self, cfg: MerlinConfig, gcfg: GuardConfig, autopilot: EndpointSpec, controller: EndpointSpec,
                 gcs: EndpointSpec | None = None, out_dir: Path | None = None,
                 clock: Callable[[], float] = time.monotonic, signing_keys: dict[str, bytes] | None = None) -> None:
        self.cfg = cfg
        self.gcfg = gcfg
        self._clock = clock
        self._t0 = clock()
        self.ap_link = _Link("autopilot", open_transport(autopilot))
        self.ctl_link = _Link("controller", open_transport(controller))
        self.gcs_link = _Link("gcs", open_transport(gcs)) if gcs is not None else None
        self.links = [x for x in (self.ap_link, self.ctl_link, self.gcs_link) if x is not None]
        for link in self.links:
            key = (signing_keys or {}).get(link.name)
            if key is not None:
                link.verify, link.signer = SigningState(key), w.LinkSigner(key)
        self.decoder = w.Decoder()
        self.enc = w.Encoder(gcfg.system_id, gcfg.component_id)
        h = cfg.home
        self.telemetry = TelemetryState(LocalFrame(h.lat_deg, h.lon_deg, h.alt_amsl_m), gcfg.telemetry_stale_s)
        self.core_cfg = build_core_config(cfg)
        self.core = TrustedCore(self.core_cfg)
        #: a fixed wing's trusted behaviours as guided points (merlin.guard.fixedwing_targets), while Merlin flies
        self.fw_stream: FixedWingStream | None = None
        self._fw_sent: tuple[float, GuidedTarget] | None = None
        self._fw_what = ""  # the kind of guided point last sent (an event records each new kind)
        self.autopilot: Autopilot | None = None
        self.modes: ModeTable | None = None
        self.ap_mode: int | None = None
        self.params: dict[str, float] = {}
        self._reader: ParamReader | None = None
        self.decision: Decision | None = None
        #: the core's inputs, built as every driver builds them (merlin.pipeline); the guard reads no RC
        self.inputs = InputBuilder(rc_connected=False)
        #: what the controller's setpoints ask of the autopilot underneath (set once the dialect is known)
        self.intent = ControllerIntent(self.telemetry.frame, standing=False)
        self.alive_since: float | None = None  # start of the controller's current unbroken liveness
        self.commands: list[GcsCommand] = []
        # behaviour requests from the controller handed to the core while Merlin flies, by the core command's
        # seq: (sender, MAVLink command or None for SET_MODE) to answer once the core has decided
        self._behaviour_asks: dict[int, tuple[tuple[int, int], int | None]] = {}
        self._behaviour_seq = 0
        self.held: _Held | None = None
        self.supervising = False  # a grant happened and the autopilot has been in the offboard mode since
        self.switch_deadline: float | None = None  # after a grant: until when the autopilot may take to switch
        self.trusted_since: float | None = None
        self.fallback_sent_t: float | None = None
        self.intervals_us: dict[int, float] = {}
        v = cfg.vehicle
        self.brake = BrakeMeter(v.reaction_time_s, v.max_horizontal_decel_mps2)
        # the fence projection's own bank, gravity and roll-out rate (merlin.config.fence_build)
        fence = self.core_cfg.fence
        self.turn = TurnMeter(v.reaction_time_s, math.radians(v.bank_limit_deg), STANDARD_GRAVITY_MPS2,
                              fence.params.roll_rate_radps if fence is not None else 0.0,
                              fence.params if fence is not None else None)
        #: set once a measured response (braking, turn) was worse than the configuration: the fence projection
        #: is known to trust this autopilot more than it deserves, so no further grant is given this session
        self.response_refusal: str | None = None
        self.counts: Counter[str] = Counter()
        self._denied_t: dict[str, float] = {}
        self._next_hb_t = 0.0
        self._next_tick_t = 0.0
        self._ap_seq = 0
        self._stop = False
        self._routing = False  # the start-up check passed: frames flow between the links
        self.out_dir = out_dir
        self.tlog: TlogWriter | None = None
        self.ap_tlog: TlogWriter | None = None
        self._events_fd: int | None = None
        self._inputs_fd: int | None = None
        if out_dir is not None:
            out_dir.mkdir(parents=True, exist_ok=True)
            self.tlog = TlogWriter(out_dir / "guard.tlog", fsync_interval_s=None)
            # the autopilot's own frames alone: the vehicle's telemetry as merlin replay reads a .tlog
            self.ap_tlog = TlogWriter(out_dir / "autopilot.tlog", fsync_interval_s=None)
            self._events_fd = os.open(out_dir / "events.jsonl", os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
            # the core's inputs, a line per tick: the session's decisions re-run exactly (inputs_log)
            self._inputs_fd = os.open(out_dir / "core_inputs.jsonl", os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
            write_effective_config(out_dir, cfg, gcfg)
        self.on_forward: Callable[[str, Frame], None] | None = None  # benchmark hook: a frame forwarded
        # tlog records not yet written: routing writes them once the frames they record have been handled
        self._log_queue: list[tuple[TlogWriter, bytes, float]] = []

    # ------------------------------------------------------------------------------------------ basics

    def t(self) -> float:
        return self._clock() - self._t0

    def event(self, record: dict[str, Any]) -> None:
        if self._events_fd is not None:
            os.write(self._events_fd, (json.dumps(record, default=str) + "\n").encode())

    def _send(self, link: _Link | None, raw: bytes, originated: bool = True) -> None:
        """Write ``raw`` to ``link``; the tlog records what the guard originates (a forwarded frame is in it
        once already, from its arrival)."""
        if link is None:
            return
        if link.signer is not None:
            signed = link.signer.sign(raw, time.time())
            if signed is None:
                self.counts[f"not sent on the signed {link.name} link: a MAVLink 1 frame"] += 1
                return
            raw = signed
        link.transport.write(raw)
        link.frames_out += 1
        if originated and self.tlog is not None:
            self._log_queue.append((self.tlog, raw, time.time()))

    @property
    def target(self) -> tuple[int, int]:
        ap = self.autopilot
        return (ap.system_id, ap.component_id) if ap is not None else (1, 1)

    def _read(self, link: _Link, timeout_s: float) -> list[Frame]:
        """The frames waiting on ``link``, logged (start-up; routing logs after it has forwarded them)."""
        frames = self._receive(link, timeout_s)
        self._write_logs()
        return frames

    def _receive(self, link: _Link, timeout_s: float) -> list[Frame]:
        """The frames waiting on ``link`` (verified where it signs); their log records are queued for
        :meth:`_write_logs`, so that a setpoint is forwarded before any file is written."""
        out: list[Frame] = []
        for data, addr in link.transport.read(timeout_s):
            frames, _errors = link.splitter.feed(data, final=link.transport.datagram)
            now_unix = time.time()
            link.frames_in += len(frames)
            if self.tlog is not None:
                self._log_queue.extend((self.tlog, fr.raw, now_unix) for fr in frames)
            if link.verify is not None:
                frames = self._verified(link, frames, now_unix)
            if frames and addr is not None and link.transport.datagram:
                link.transport.remote = addr  # answer whoever sent valid (and, when signing, verified) MAVLink
            if link is self.ap_link and self.ap_tlog is not None:
                self._log_queue.extend((self.ap_tlog, fr.raw, now_unix) for fr in frames)
            out.extend(frames)
        return out

    def _write_logs(self) -> None:
        """Write the queued tlog records, in the order they were queued (a frame received, then what the guard
        sent in answer)."""
        q = self._log_queue
        for tlog, raw, unix_s in q:
            tlog.write(raw, unix_s)
        q.clear()

    def _verified(self, link: _Link, frames: list[Frame], now_unix: float) -> list[Frame]:
        """The frames of a signed link whose signature verifies with its key (MAVLink's replay rule included):
        an unsigned or wrongly signed frame is dropped before anything reads it, so it neither reaches the
        autopilot nor counts as the controller's liveness, request or setpoint."""
        v = link.verify
        assert v is not None
        v.advance_clock(now_unix)
        kept = []
        for fr in frames:
            check = v.check(fr)
            if check is SignatureCheck.OK:
                kept.append(fr)
                continue
            reason = f"dropped: {link.name} frame {check.value}"
            self.counts[reason] += 1
            t = self.t()
            if t - self._denied_t.get(reason, -math.inf) >= STATUSTEXT_REPEAT_S:
                self._denied_t[reason] = t
                self.event({"t": t, "type": "guard_signing_dropped", "link": link.name, "check": check.value,
                            "msg_id": fr.msg_id, "system_id": fr.system_id})
        return kept

    # ------------------------------------------------------------------------------------ start-up

    def start(self) -> Autopilot:
        """Detect the autopilot, check its failsafe parameters, request telemetry. Raises GuardRefused."""
        deadline = self.t() + self.gcfg.heartbeat_timeout_s
        while self.autopilot is None:
            if self.t() > deadline:
                raise GuardRefused(None, [], f"no autopilot HEARTBEAT on the autopilot link within "
                                             f"{self.gcfg.heartbeat_timeout_s:g} s (guard.heartbeat_timeout_s)")
            self._send(self.ap_link, self.enc.heartbeat())
            for fr in self._read(self.ap_link, 0.2):
                self._on_autopilot(fr, self.t())
        ap = self.autopilot
        req = requirements(ap)
        self._reader = ParamReader(req.required, req.optional + req.gcs_sysid, self.gcfg.param_timeout_s)
        while not self._reader.done(self.t()):
            for name in self._reader.due(self.t()):
                self._send(self.ap_link, self.enc.param_request_read(self.target, name))
            for fr in self._read(self.ap_link, 0.05):
                self._on_autopilot(fr, self.t())
        self.params = dict(self._reader.values)
        self._reader = None
        refusals = check(ap, self.params, self.gcfg)
        self.event({"t": self.t(), "type": "guard_start_check", "autopilot": ap.describe(), "params": self.params,
                    "refusals": [r.text() for r in refusals]})
        if refusals:
            raise GuardRefused(ap, refusals)
        gcs_sysid = next((self.params[n] for n in req.gcs_sysid if n in self.params), None)
        if ap.dialect is Dialect.ARDUPILOT and gcs_sysid is not None:
            # ArduPilot's GCS failsafe watches heartbeats from this system: the guard is that heartbeat
            self.enc = w.Encoder(int(gcs_sysid), self.gcfg.component_id)
        for s in stream_requests(ap.dialect, self.gcfg.telemetry_rate_hz):
            self.intervals_us[s.message_id] = s.interval_us
            self._send(self.ap_link, self.enc.command_long(self.target, w.MAV_CMD_SET_MESSAGE_INTERVAL,
                                                           (float(s.message_id), s.interval_us)))
        for link in (self.ctl_link, self.gcs_link):
            while link is not None and (stale := self._read(link, 0.0)):
                self.counts["dropped: sent before the start-up check passed"] += len(stale)
        self._routing = True
        self.event({"t": self.t(), "type": "guard_started", "autopilot": ap.describe()})
        return ap

    # ------------------------------------------------------------------------------------- routing

    def _on_autopilot(self, fr: Frame, t: float) -> None:
        rec = self.decoder.typed(fr) if fr.msg_id in w.TYPED_IDS else None
        if isinstance(rec, w.Heartbeat):
            if self.autopilot is None:
                found = detect(rec.autopilot, rec.mav_type, fr.system_id, fr.component_id)
                if found is not None:
                    self.autopilot, self.modes = found, mode_table(found)
                    # ArduPlane's GUIDED keeps a target of its own between the controller's messages; PX4's
                    # fixed wing flies whatever point it has at the transfer (merlin.guard.intent)
                    fw = found.vehicle is VehicleClass.FIXED_WING
                    self.intent = ControllerIntent(self.telemetry.frame, found.dialect is Dialect.ARDUPILOT and fw,
                                                   found.dialect is Dialect.PX4 and fw)
            if self.autopilot is not None and (fr.system_id, fr.component_id) == self.target:
                self.ap_mode = rec.custom_mode
                self._ap_seq = fr.seq
                self.telemetry.on(t, rec)
                if not self._routing:
                    return
                raw = fr.raw
                if self.gcs_link is not None:
                    self._send(self.gcs_link, raw, originated=False)
                shown = self._heartbeat_for_controller(rec, raw)
                self._send(self.ctl_link, shown, originated=shown is not raw)
                return
        elif isinstance(rec, w.ParamValue):
            if self._reader is not None and self.autopilot is not None:
                bytewise = self.autopilot.dialect is Dialect.PX4
                self._reader.on_value(rec.param_id, w.param_number(rec, bytewise))
        elif rec is not None and fr.system_id == self.target[0]:
            self.telemetry.on(t, rec)
        if not self._routing:
            return
        self._send(self.ctl_link, fr.raw, originated=False)
        if self.gcs_link is not None:
            self._send(self.gcs_link, fr.raw, originated=False)

    def _heartbeat_for_controller(self, hb: w.Heartbeat, raw: bytes) -> bytes:
        d, m = self.decision, self.modes
        if (d is None or m is None or not self.supervising or d.authority is Authority.EXPERIMENTAL
                or not m.is_offboard(hb.custom_mode)):
            return raw
        shown = m.behaviour_modes.get(d.behavior, m.fallback[next(iter(m.fallback))])
        return self.enc.heartbeat_as(hb, shown, self.target, self._ap_seq)

    def _gate_context(self) -> GateContext:
        d = self.decision
        experimental = d is not None and d.authority is Authority.EXPERIMENTAL
        state = self.telemetry._last_state
        refusal = None
        if state.nav_mode is NavMode.LOST:
            refusal = "navigation: " + "; ".join(self.telemetry.faults(self.t()))
        elif d is not None:
            fence = next((m for m in d.monitors if m.name == MonitorId.GEOFENCE and m.tripped), None)
            if fence is not None:
                refusal = f"outside the fence ({fence.reason.describe()})"
        assert self.modes is not None
        offboard = self.ap_mode is not None and self.modes.is_offboard(self.ap_mode)
        return GateContext(self.modes, experimental, offboard, self._trusted_flying(), state.landed, refusal,
                           self.intervals_us)

    def _trusted_flying(self) -> bool:
        d = self.decision
        return self.supervising and d is not None and d.authority is not Authority.EXPERIMENTAL

    def _on_controller(self, fr: Frame, t: float) -> None:
        if self.modes is None:
            return  # nothing reaches an autopilot the guard has not recognised and checked
        rec = self.decoder.typed(fr) if fr.msg_id in w.TYPED_IDS else None
        if fr.msg_id == w.HEARTBEAT or fr.msg_id in w.SETPOINT_IDS:
            # a setpoint stream is the controller's liveness too, as PX4's offboard loss timeout counts it
            hb_t = self.inputs.heartbeat_t
            if hb_t is None or t - hb_t > self.cfg.watchdogs.controller_heartbeat.timeout_s:
                self.alive_since = t
            self.inputs.controller_heartbeat(t)
        if fr.msg_id in w.SETPOINT_IDS and fr.msg_id != w.SET_ACTUATOR_CONTROL_TARGET:
            sp = self.intent.on_setpoint(rec, self.telemetry._last_state)
            if isinstance(sp, Refused):
                # a setpoint the core cannot judge never reaches the autopilot (merlin serve drops it too)
                self._deny(fr, rec, sp.detail, t)
                return
            if sp is not None:
                self.inputs.setpoint(sp, t)
        elif fr.msg_id == w.SET_ACTUATOR_CONTROL_TARGET:
            self.inputs.setpoint(Setpoint(SetpointKind.VELOCITY), t)
        v = classify(fr.msg_id, rec, self._gate_context())
        if v.route is Route.FORWARD and self.intent.standing and not self._goto(rec, t):
            self._deny(fr, rec, "goto not judged: the point is not one Merlin reads (see events)", t)
            return
        if v.route is Route.FORWARD:
            self._forward_to_autopilot(fr)
        elif v.route is Route.DROP:
            self.counts[f"dropped: {v.reason}"] += 1
        elif v.route is Route.DENY:
            self._deny(fr, rec, v.reason, t)
        elif v.route is Route.REQUEST:
            self._on_request(fr, rec, v.reason, t)
        elif v.route is Route.BEHAVIOUR:
            self._on_behaviour_request(fr, rec, v.reason, v.behaviour, t)
        elif v.route is Route.ACCEPT:
            if isinstance(rec, w.CommandIn):
                self._send(self.ctl_link, w.Encoder(*self.target).command_ack(
                    (fr.system_id, fr.component_id), rec.command, w.MAV_RESULT_ACCEPTED))
            self.counts[f"answered: {v.reason}"] += 1
        elif v.route is Route.RELEASE:
            self.inputs.request((AuthorityRequest(RequestKind.RELEASE, t_s=t),))
            self.event({"t": t, "type": "guard_release", "detail": v.reason})
            self._forward_to_autopilot(fr)

    def _on_request(self, fr: Frame, rec: object | None, reason: str, t: float) -> None:
        """A standard request, as ``merlin serve`` takes it (ICD section 6): one PX4 would accept (setpoints
        streaming) is never denied for Merlin's own timing. While the controller's liveness is younger than
        ``handover.heartbeat_alive_min_s`` the guard holds it, answering COMMAND_ACK IN_PROGRESS (and again
        every 0.5 s, and to each retransmission), and passes it to the core once the rule can be met."""
        if self.response_refusal is not None:
            self._deny(fr, rec, self.response_refusal, t)
            return
        cmd = rec.command if isinstance(rec, w.CommandIn) else None
        sender = (fr.system_id, fr.component_id)
        h = self.held
        if h is not None and h.sender == sender and h.command == cmd:
            self._in_progress(h, t)  # a retransmission (MAVSDK resends after 0.5 s): the same request
            return
        alive = 0.0 if self.alive_since is None else t - self.alive_since
        need = self.cfg.handover.heartbeat_alive_min_s + HOLD_MARGIN_S
        sp_t = self.inputs.setpoint_t
        streaming = sp_t is not None and t - sp_t <= self.cfg.links.offboard_loss_timeout_s
        self.held = _Held(fr.raw, cmd, sender, t)
        if streaming and alive < need and self.alive_since is not None:
            self.held.release_t = self.alive_since + need
            self._in_progress(self.held, t)
            self.event({"t": t, "type": "guard_request_held", "detail": f"{reason}: controller alive {alive:.2f} s"
                        f" of handover.heartbeat_alive_min_s {self.cfg.handover.heartbeat_alive_min_s:g}"})
            return
        self.inputs.request((AuthorityRequest(RequestKind.REQUEST, t_s=t),))
        self.event({"t": t, "type": "guard_request", "detail": reason})

    def _in_progress(self, h: _Held, t: float) -> None:
        if h.command is not None:
            self._send(self.ctl_link, w.Encoder(*self.target).command_ack(h.sender, h.command, MAV_RESULT_IN_PROGRESS))
        h.next_progress_t = t + IN_PROGRESS_INTERVAL_S

    def _advance_held(self, t: float) -> None:
        h = self.held
        if h is None or h.release_t is None:
            return
        hb_t = self.inputs.heartbeat_t
        if hb_t is None or t - hb_t > self.cfg.links.offboard_loss_timeout_s:
            # the controller went silent while its request was held: PX4 would refuse OFFBOARD now (logged
            # before it is answered, as every denial: _deny)
            self.event({"t": t, "type": "guard_request_dropped", "detail": "the controller went silent"})
            if h.command is not None:
                self._send(self.ctl_link, w.Encoder(*self.target).command_ack(h.sender, h.command, w.MAV_RESULT_DENIED))
            self.held = None
            return
        if t >= h.release_t:
            h.release_t = None
            self.inputs.request((AuthorityRequest(RequestKind.REQUEST, t_s=t),))
            self.event({"t": t, "type": "guard_request", "detail": "held request passed to the core"})
        elif t >= h.next_progress_t:
            self._in_progress(h, t)

    def _goto(self, rec: object | None, t: float) -> bool:
        """ArduPlane's GUIDED point (DO_REPOSITION as COMMAND_INT, MISSION_ITEM_INT ``current`` 2) becomes the
        standing target the core judges; False for one the core cannot read (it is then not forwarded)."""
        state = self.telemetry._last_state
        if isinstance(rec, w.CommandIn) and rec.command == w.MAV_CMD_DO_REPOSITION:
            if not rec.is_int:
                self.event({"t": t, "type": "guard_goto_refused",
                            "detail": "DO_REPOSITION as COMMAND_LONG: Plane reads it as COMMAND_INT (a frame)"})
                return False
            frame = rec.frame
            sp = self.intent.on_goto(frame, rec.params[4] * 1e-7, rec.params[5] * 1e-7, rec.params[6], state)
        elif isinstance(rec, w.MissionItemIn) and rec.current == 2:
            sp = self.intent.on_goto(rec.frame, rec.lat_deg, rec.lon_deg, rec.alt_m, state)
        else:
            return True
        if isinstance(sp, Refused):
            self.event({"t": t, "type": "guard_goto_refused", "detail": sp.detail})
            return False
        self.inputs.setpoint(sp, t)
        self.event({"t": t, "type": "guard_goto", "target_ned_m": list(sp.pos_ned_m)})
        return True

    def _forward_to_autopilot(self, fr: Frame) -> None:
        self._send(self.ap_link, fr.raw, originated=False)
        if self.on_forward is not None:
            self.on_forward("controller", fr)

    def _deny(self, fr: Frame, rec: object | None, reason: str, t: float) -> None:
        self.counts[f"denied: {reason}"] += 1
        tell = t - self._denied_t.get(reason, -math.inf) >= STATUSTEXT_REPEAT_S
        if tell:
            # recorded before the controller is answered: whoever holds the answer finds it in the log (the
            # test that asks again after a weak escape turn reads the log as soon as its DENIED arrives)
            self._denied_t[reason] = t
            self.event({"t": t, "type": "guard_denied", "detail": reason})
        if isinstance(rec, w.CommandIn):
            self._send(self.ctl_link, w.Encoder(*self.target).command_ack(
                (fr.system_id, fr.component_id), rec.command, w.MAV_RESULT_DENIED))
        if tell:
            self._send(self.ctl_link, self.enc.statustext(w.MAV_SEVERITY_WARNING, f"Merlin: {reason}"))

    def _on_behaviour_request(self, fr: Frame, rec: object, reason: str, kind: GcsCommandKind | None,
                              t: float) -> None:
        """The controller asks for hold, return or land while Merlin's trusted autopilot flies: the core gets
        it as that command (as merlin serve takes it from the controller link); the answer is the core's."""
        assert kind is not None
        self._behaviour_seq += 1
        cmd = rec.command if isinstance(rec, w.CommandIn) else None
        self._behaviour_asks[self._behaviour_seq] = ((fr.system_id, fr.component_id), cmd)
        self.commands.append(GcsCommand(kind, seq=self._behaviour_seq))
        self.event({"t": t, "type": "guard_behaviour_request", "detail": reason, "command": kind.name})

    def _on_gcs(self, fr: Frame, t: float) -> None:
        if fr.msg_id == w.HEARTBEAT:
            self.inputs.gcs_heartbeat(t)
        self._send(self.ap_link, fr.raw, originated=False)  # the operator's link is trusted: everything passes

    # ---------------------------------------------------------------------------------------- tick

    def _arm_sync(self, armed: bool) -> None:
        d = self.decision
        core_armed = d.armed if d is not None else False
        if armed != core_armed:
            # the autopilot arms and disarms; the core follows it (forced: the autopilot ran its own checks)
            self.commands.append(GcsCommand(GcsCommandKind.ARM if armed else GcsCommandKind.DISARM, force=True))

    def tick(self) -> Decision:
        t = self.t()
        state = self.telemetry.vehicle_state(t)
        self._arm_sync(state.armed)
        m = self.modes
        # the autopilot's HEARTBEAT comes at 1 Hz: while a mode command the guard forwarded is on its way, the
        # vehicle is taken to be in the offboard mode already, so that trusted setpoints stream from the first
        # tick Merlin needs them (PX4 leaves OFFBOARD after COM_OF_LOSS_T without them)
        switching = self.switch_deadline is not None and t < self.switch_deadline
        in_offboard = m is not None and ((self.ap_mode is not None and m.is_offboard(self.ap_mode)) or switching)
        d0 = self.decision
        if m is not None and self.ap_mode is not None and m.is_offboard(self.ap_mode):
            self.switch_deadline = None
        if self.supervising and not in_offboard and self.fallback_sent_t is None and not switching:
            # someone else (the ground station, the RC switch, the autopilot's own failsafe) took the vehicle
            # out of the offboard mode: the guard stops flying it, and the controller loses authority
            self.supervising = False
            if d0 is not None and d0.authority is Authority.EXPERIMENTAL:
                self.inputs.request((AuthorityRequest(RequestKind.RELEASE, t_s=t),))
            self.event({"t": t, "type": "guard_standby", "detail": f"autopilot in {m.name(self.ap_mode or 0) if m else '?'}"})
        self._advance_held(t)
        if self.gcs_link is None:  # no ground station to watch: its link is never the reason for a failsafe
            self.inputs.gcs_heartbeat(t)
        if self.intent.standing and not self.intent.attitude:
            # ArduPlane's GUIDED target stands until replaced: it is what the autopilot flies every tick
            self.inputs.setpoint(self.intent.standing_setpoint(state), t)
        inputs = self.inputs.build(state, tuple(self.commands))
        self.commands.clear()
        d = self.core.step(t, inputs)
        self.decision = d
        for e in d.events:
            self.event(e.to_dict())
            self._on_core_event(e.kind, e, t)
        if self._routing:
            # a setpoint that arrived during the core's step is judged by its decision and forwarded now, not
            # after the rest of the tick (the input log, the trusted stream): the gate reads the decision, whose
            # events have been acted on, and the controller's frames feed the next tick's inputs, built already
            self._route(self.ctl_link)
        if self._inputs_fd is not None:
            os.write(self._inputs_fd, inputs_log.encode(t, inputs).encode())
        if d0 is not None and d0.authority is Authority.EXPERIMENTAL and d.authority is not Authority.EXPERIMENTAL:
            self.intent.reset()
            # a new stage per revocation: it enters the behaviour afresh
            self.fw_stream, self._fw_sent, self._fw_what = None, None, ""
            self.trusted_since = t
            self.fallback_sent_t = None
            if self.modes is not None and self.modes.streams_setpoints:
                # a multirotor brakes to a stop; a fixed wing cannot: it turns, and its first turn is measured
                self.brake.start(t, state.vel_ned_mps)
            elif self.modes is not None and not state.landed:
                self.turn.start(t, state)
        braked = self.brake.update(t, state.vel_ned_mps)
        if braked is not None:
            self._on_brake_measured(braked, t)
        turned = self.turn.update(t, state)
        if turned is not None:
            self._on_turn_measured(turned, t)
        if (self._trusted_flying() and in_offboard) or (self.fallback_sent_t is not None and self.supervising):
            self._fly_trusted(d, t)
        if t >= self._next_hb_t:
            self._next_hb_t = t + HEARTBEAT_PERIOD_S
            self._send(self.ap_link, self.enc.heartbeat())
        self._write_logs()
        return d

    def _on_brake_measured(self, m: BrakeMeasurement, t: float) -> None:
        ok = m.reaction_ok and m.decel_ok
        self.event({"t": t, "type": "guard_brake_measured", "ok": ok, "speed0_mps": m.speed0_mps,
                    "reaction_s": m.reaction_s, "decel_mps2": m.decel_mps2, "detail": m.text()})
        if not ok:
            self._response_worse("brakes worse than configured", "vehicle.reaction_time_s, "
                                 "vehicle.max_horizontal_decel_mps2", m.text(), t)

    def _on_turn_measured(self, m: TurnMeasurement, t: float) -> None:
        self.event({"t": t, "type": "guard_turn_measured", "ok": m.ok, "speed_mps": m.speed_mps,
                    "commanded": m.commanded, "heading_change_deg": m.heading_change_deg,
                    "established_s": m.established_s, "bank_deg": m.bank_deg, "turn_rate_degps": m.turn_rate_degps,
                    "radius_m": m.radius_m, "radius_limit_m": m.radius_limit_m,
                    "radius_inner_m": m.radius_inner_m, "detail": m.text()})
        if m.ok is False:
            fields = "vehicle.reaction_time_s, vehicle.bank_limit_deg"
            if m.inner_ok is False:
                fields += ", vehicle.bank_max_deg"
            self._response_worse(f"turns {' and '.join(m.problems())} than configured", fields, m.text(), t)

    def _response_worse(self, what: str, fields: str, detail: str, t: float) -> None:
        """The autopilot answered a revocation worse than the fence projection assumes: warned on the links,
        and no further grant this session (the projection would judge the next flyaway on the same optimistic
        figures); the fix is the configuration, with the guard restarted."""
        text = f"Merlin: autopilot {what} (see events)"
        for link in (self.ctl_link, self.gcs_link):
            self._send(link, self.enc.statustext(w.MAV_SEVERITY_WARNING, text))
        if self.response_refusal is None:
            self.response_refusal = (f"no grant: the autopilot {what} ({detail}); set {fields} to what it flies "
                                     "and restart the guard")
            self.event({"t": t, "type": "guard_grants_refused", "detail": self.response_refusal})

    def _on_core_event(self, kind: EventKind, e: Any, t: float) -> None:
        if kind is EventKind.GRANTED:
            # the standard flow has no ACK message: the controller's mode command is its acknowledgement
            self.inputs.request((AuthorityRequest(RequestKind.ACK, seq=e.seq, t_s=t),))
        elif kind is EventKind.AUTHORITY and e.to is Authority.EXPERIMENTAL:
            # the transfer is done (the core checked the first setpoint against the vehicle): only now does the
            # autopilot get the mode command, so it never flies the controller's setpoints before the core
            # has handed over
            self.supervising = True
            self.brake.cancel()  # a measurement still running would measure the controller's flight
            self.turn.cancel()
            self.intent.enter(self.telemetry._last_state)
            self.switch_deadline = t + SWITCH_TIMEOUT_S
            self.trusted_since = None
            self.fallback_sent_t = None
            if self.held is not None:
                self._send(self.ap_link, self.held.raw, originated=False)
                self.held = None
        elif kind is EventKind.DENIED and self.held is not None:
            reason = e.reason.describe()
            if self.held.command is not None:
                self._send(self.ctl_link, w.Encoder(*self.target).command_ack(
                    self.held.sender, self.held.command, w.MAV_RESULT_DENIED))
            self._send(self.ctl_link, self.enc.statustext(w.MAV_SEVERITY_WARNING, f"Merlin: denied: {reason}"))
            self.held = None
        elif kind is EventKind.COMMAND_ACK and e.seq in self._behaviour_asks:
            sender, cmd = self._behaviour_asks.pop(e.seq)
            if cmd is not None:
                result = w.MAV_RESULT_ACCEPTED if e.accepted else w.MAV_RESULT_DENIED
                self._send(self.ctl_link, w.Encoder(*self.target).command_ack(sender, cmd, result))
            if not e.accepted:
                self._send(self.ctl_link, self.enc.statustext(
                    w.MAV_SEVERITY_WARNING, f"Merlin: {e.command.name if e.command else 'command'} refused: "
                                            f"{e.reason.describe()}"))
        elif kind is EventKind.REVOKED:
            text = f"Merlin: revoked: {e.reason.describe()}"
            self._send(self.ctl_link, self.enc.statustext(w.MAV_SEVERITY_WARNING, text))
            if self.gcs_link is not None:
                self._send(self.gcs_link, self.enc.statustext(w.MAV_SEVERITY_WARNING, text))

    def _fly_trusted(self, d: Decision, t: float) -> None:
        assert self.modes is not None
        if self.trusted_since is None:
            self.trusted_since = t
        since = self.trusted_since
        state = self.telemetry._last_state
        fw_target = None
        if not self.modes.streams_setpoints and self.gcfg.fallback_mode is None:
            if self.fw_stream is None:
                self.fw_stream = FixedWingStream(self.cfg, self.core_cfg, state, 1.0 / self.gcfg.rate_hz)
            n_notes = len(self.fw_stream.notes)
            fw_target = self.fw_stream.target(t, d, state)
            for note in self.fw_stream.notes[n_notes:]:
                self.event({**note, "t": t})
            if fw_target.what == "turn" and t - since < 1.5 / self.gcfg.rate_hz:
                # the escape turn starts in the tick of the revocation, to the side of its abeam point: its
                # reaction is judged
                course = FixedWingStream.course(state)
                dn, de = fw_target.north_m - state.pos_ned_m[0], fw_target.east_m - state.pos_ned_m[1]
                self.turn.commanded(right=math.cos(course) * de - math.sin(course) * dn > 0.0)
        out: TrustedOutput = trusted_output(d, self.modes, self.gcfg, t - since, state, fw_target)
        if out.target is not None:
            self._send_guided_target(out.target, t)
            return
        if out.mode is not None:
            if self.ap_mode == out.mode:
                return
            if self.fallback_sent_t is None or t - self.fallback_sent_t >= 0.5:
                self.fallback_sent_t = t
                self._send(self.ap_link, self.enc.command_long(
                    self.target, w.MAV_CMD_DO_SET_MODE, self.modes.set_mode_params(out.mode)))
                self.event({"t": t, "type": "guard_fallback_mode", "mode": self.modes.name(out.mode)})
            return
        if out.vel_ned_mps is not None:
            self._send(self.ap_link, self.enc.velocity_setpoint(int(t * 1000), self.target, out.vel_ned_mps,
                                                                out.yaw_rad))

    def _send_guided_target(self, g: GuidedTarget, t: float) -> None:
        """A fixed wing's trusted point: PX4's offboard needs it streamed every tick; ArduPlane's GUIDED keeps
        its point, so it is sent when it moves (a turn's abeam point every GUIDED_TURN_PERIOD_S, so the turn
        goes on) and again every GUIDED_REPEAT_S (a lost command is repeated)."""
        assert self.autopilot is not None
        lat, lon, _ = self.telemetry.frame.to_geodetic(g.north_m, g.east_m)
        alt = self.telemetry.frame.alt0_amsl_m + g.height_m
        if g.what != self._fw_what:
            self._fw_what = g.what
            self.event({"t": t, "type": "guard_guided_target", "what": g.what,
                        "target_ned_m": [g.north_m, g.east_m, -g.height_m], "loiter_radius_m": g.loiter_radius_m})
        if self.autopilot.dialect is Dialect.PX4:
            self._send(self.ap_link, self.enc.position_target_global(int(t * 1000), self.target, lat, lon, alt))
            return
        last = self._fw_sent
        if last is not None:
            since, prev = t - last[0], last[1]
            moved = math.hypot(g.north_m - prev.north_m, g.east_m - prev.east_m) > GUIDED_MOVE_M or (
                abs(g.height_m - prev.height_m) > GUIDED_MOVE_M or g.what != prev.what)
            sliding = g.what in ("turn", "run-out")  # a point that moves with the aircraft
            period = GUIDED_TURN_PERIOD_S if sliding else GUIDED_REPEAT_S
            if since < period and not (moved and not sliding):
                return
        self._fw_sent = (t, g)
        self._send(self.ap_link, self.enc.reposition(self.target, lat, lon, alt, g.loiter_radius_m, g.clockwise))

    # ---------------------------------------------------------------------------------------- loop

    def poll(self, until_t: float) -> None:
        """Route whatever arrives until ``until_t`` (guard clock)."""
        fds = {x.fileno(): x for x in self.links if x.fileno() >= 0}
        while True:
            remaining = until_t - self.t()
            if remaining <= 0:
                break
            try:
                ready, _, _ = select.select(list(fds), [], [], remaining)
            except (OSError, ValueError):
                ready = list(fds)
                time.sleep(min(remaining, 0.001))
            # the controller's frames first: a setpoint waiting behind a burst of telemetry is added latency
            for fd in sorted(ready, key=lambda f: fds[f] is not self.ctl_link):
                self._route(fds[fd])
            if not ready:
                break

    def _route(self, link: _Link) -> None:
        """Handle what waits on ``link`` now, then write its logs (after the forwarding, not before it)."""
        try:
            for fr in self._receive(link, 0.0):
                now = self.t()
                if link is self.ap_link:
                    self._on_autopilot(fr, now)
                elif link is self.ctl_link:
                    self._on_controller(fr, now)
                else:
                    self._on_gcs(fr, now)
        finally:
            self._write_logs()

    def run(self, duration_s: float | None = None) -> None:
        period = 1.0 / self.gcfg.rate_hz
        end = None if duration_s is None else self.t() + duration_s
        self._next_tick_t = self.t()
        while not self._stop and (end is None or self.t() < end):
            self.poll(self._next_tick_t)
            if self.t() >= self._next_tick_t:
                self.tick()
                self._next_tick_t += period
                if self.t() - self._next_tick_t > 10 * period:
                    self._next_tick_t = self.t() + period  # far behind (a stall): re-anchor, do not burst

    def stop(self) -> None:
        self._stop = True

    def close(self) -> None:
        self._write_logs()
        self.event({"t": self.t(), "type": "guard_stopped", "counts": dict(self.counts)})
        for link in self.links:
            link.transport.close()
        for tl in (self.tlog, self.ap_tlog):
            if tl is not None:
                tl.close()
        for fd in (self._events_fd, self._inputs_fd):
            if fd is not None:
                os.close(fd)
        self._events_fd = self._inputs_fd = None

