"""``merlin serve``: fly the simulated vehicle under the trusted core in real time, speaking MAVLink over UDP
like PX4 SITL (GCS: bind 18570, send to 127.0.0.1:14550; offboard API: bind 14580, send to
127.0.0.1:14540), answering whoever replies. With no arguments it uses the built-in configuration.

Before the links open, the configuration goes through the cross-checks against ``--vehicle``
(:mod:`merlin.config.crosschecks`): an error refuses to fly unless ``--accept-risk`` accepts it by id.

PX4 SITL's conventions, so that code written against PX4 SITL runs unchanged (icd/ICD.md section 6.6):

* Home: the built-in configuration starts at PX4 SITL's default home, Zurich Irchel Park (47.397742 N,
  8.545594 E, 488 m AMSL); PX4_HOME_LAT, PX4_HOME_LON and PX4_HOME_ALT move it, for the built-in
  configuration or a file's. A configuration's fence given relative to home (``*_ne_m``) follows the home;
  one given in latitude/longitude does not, so moving the home of such a file is refused with an error
  naming the fence field (the range would be left behind, thousands of kilometres away).
* ``--instance N`` as PX4's multi-vehicle SITL (``px4 -i N``, ROMFS ``px4-rc.mavlink``): GCS link bound to
  18570+N (sending to 14550), offboard link bound to 14580+N sending to 14540+N (14549 above instance 9),
  system id N+1. An explicit port or ``--sysid`` option wins.

Exit codes: 0 stopped normally (duration elapsed, SIGINT or SIGTERM), 2 invalid input or a configuration
refused by a cross-check error.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import logging
import os
import sys
from pathlib import Path
from typing import Any, cast


def register(sub: Any) -> None:
    p = sub.add_parser("serve", help="run the simulated vehicle and the trusted core in real time over MAVLink")
    p.add_argument("--config", default=None, help="configuration YAML (default: the built-in MerlinConfig())")
    p.add_argument("--vehicle", default="quadrotor_default",
                   help="the simulated vehicle: a multirotor in sims/vehicles (default quadrotor_default) or the "
                        "JSBSim fixed wing 'aerosonde' (it starts on its catapult: arm, then takeoff launches it; "
                        "without --config it flies the built-in fixed-wing configuration)")
    p.add_argument("--rate-hz", type=float, default=250.0, help="core and simulation tick rate (default 250)")
    p.add_argument("--core-dt-s", type=float, default=None,
                   help="the trusted core's period, a whole number of ticks of 1/--rate-hz up to 0.02 s (default: "
                        "10 ms rounded down to whole ticks, 8 ms at the default 250 Hz; 1/--rate-hz for every "
                        "tick); what arrives between its ticks waits for the next one, as in merlin sim")
    p.add_argument("--nav-dt-s", type=float, default=None,
                   help="the IMU voter's and the fusion EKF's period, a whole number of ticks up to 0.02 s, as PX4's "
                        "EKF2_PREDICT_US (default: as --core-dt-s); an output predictor gives the state between")
    p.add_argument("--speedup", type=float, default=1.0, help="run faster than real time (tests), default 1")
    p.add_argument("--instance", "-i", type=int, default=0,
                   help="vehicle instance, as PX4's multi-vehicle SITL (px4 -i N): ports offset by N, system id N+1")
    p.add_argument("--sysid", type=int, default=None, help="Merlin's MAVLink system id (default instance + 1)")
    p.add_argument("--compid", type=int, default=1, help="Merlin's component id (default 1, AUTOPILOT1)")
    p.add_argument("--gcs-port", type=int, default=None, help="ground-station remote UDP port (default 14550)")
    p.add_argument("--gcs-bind-port", type=int, default=None,
                   help="local UDP port of the GCS link (default 18570 + instance)")
    p.add_argument("--offboard-port", type=int, default=None,
                   help="offboard-API remote UDP port (default 14540 + instance; 14549 above instance 9, as PX4)")
    p.add_argument("--offboard-bind-port", type=int, default=None,
                   help="local UDP port of the controller link (default 14580 + instance)")
    p.add_argument("--remote-host", default="127.0.0.1", help="where telemetry goes until a peer replies")
    p.add_argument("--no-gcs", action="store_true", help="no ground-station link")
    p.add_argument("--serial", default=None, metavar="DEV:BAUD",
                   help="put the controller link on a serial device instead of UDP, e.g. /dev/ttyUSB0:921600")
    p.add_argument("--signing-key", default=None, metavar="FILE",
                   help="signing key file (64 hex digits, 44 base64 characters or 32 bytes) for both links, "
                        "signatures required on both; overrides links.*.signing in the configuration")
    p.add_argument("--allow-unsigned-provisioning", action="store_true", default=None,
                   help="accept a first SETUP_SIGNING in the clear on both links (bench links only); overrides "
                        "links.*.signing.allow_unsigned_provisioning")
    p.add_argument("--controller-sysids", default=None,
                   help="allow-list of controller system ids, e.g. 1,42; overrides links.controller")
    p.add_argument("--gcs-sysids", default=None,
                   help="allow-list of ground-station system ids, e.g. 255; overrides links.gcs")
    p.add_argument("--params-locked", action="store_true",
                   help="refuse every PARAM_SET, on the ground too: fly exactly the reviewed configuration file "
                        "(links.params_locked: true in the file does the same; this option cannot unlock it)")
    p.add_argument("--out", default=None, help="directory for flight.tlog and events.jsonl "
                                               "(default out/serve/<UTC timestamp>)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many simulated seconds")
    p.add_argument("--no-gc-tuning", action="store_true", help="leave Python's garbage collector automatic")
    p.add_argument("--realtime-priority", type=int, default=0, metavar="N",
                   help="run the tick scheduler SCHED_FIFO at priority N and lock the process in RAM (mlockall) "
                        "(Linux, needs the privilege); 0 off")
    p.add_argument("--autopilot-only", action="store_true",
                   help="behave as a plain autopilot under merlin guard: no geofence, and the envelope, geofence, "
                        "RC, GCS-link and low-battery monitors act on nothing; the offboard-loss failsafe "
                        "(COM_OF_LOSS_T / COM_OBL_RC_ACT) and the estimator and critical-battery failsafes stay")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--accept-risk", action="append", default=None, metavar="XCNNN[,XCNNN]",
                   help="fly despite this cross-check error (docs/crosschecks.md; repeatable); logged and written "
                        "to crosschecks.json in --out")
    p.set_defaults(func=run)


def _ids(text: str | None, what: str) -> frozenset[int] | None:
    from merlin.config.loader import ConfigError

    if text is None:
        return None
    try:
        ids = frozenset(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise ConfigError("--" + what, [f"{text!r}: expected comma-separated integers 1..255"]) from None
    if not ids or not all(1 <= x <= 255 for x in ids):
        raise ConfigError("--" + what, [f"{text!r}: expected comma-separated integers 1..255"])
    return ids


def _load(path: str | None) -> tuple[Any, Path]:
    """The configuration, validated with the directory of its file known, so that the ``links:`` key files
    are checked (relative to that directory) as part of validation; and that directory."""
    from merlin.config.loader import read_yaml_file, validate_model
    from merlin.config.models import MerlinConfig

    if path is None:
        return MerlinConfig(), Path.cwd()
    data, lines = read_yaml_file(path)
    config_dir = Path(path).resolve().parent
    return validate_model(MerlinConfig, data, path, lines, {"config_dir": config_dir}), config_dir


#: PX4 SITL's default home (Tools/simulation: Zurich Irchel Park), what PX4's examples hard-code.
PX4_SITL_HOME = (47.397742, 8.545594, 488.0)
#: The environment variables PX4 SITL reads for its home, with the configuration field each sets.
PX4_HOME_ENV = (("PX4_HOME_LAT", "lat_deg"), ("PX4_HOME_LON", "lon_deg"), ("PX4_HOME_ALT", "alt_amsl_m"))


def sitl_ports(instance: int) -> dict[str, int]:
    """The UDP ports of PX4 SITL instance ``instance`` (ROMFS/px4fmu_common/init.d-posix/px4-rc.mavlink)."""
    return {"gcs_bind_port": 18570 + instance, "gcs_port": 14550, "offboard_bind_port": 14580 + instance,
            "offboard_port": 14540 + instance if instance <= 9 else 14549}


def _absolute_fence_fields(geofence: Any) -> list[str]:
    """The fence fields given in latitude/longitude (they do not move with home)."""
    out = []
    for kind in ("inclusion_polygons", "exclusion_polygons"):
        for k, poly in enumerate(getattr(geofence, kind)):
            if poly.vertices_deg is not None or poly.holes_deg:
                out.append(f"geofence.{kind}[{k}].{'vertices_deg' if poly.vertices_deg is not None else 'holes_deg'}")
    for kind in ("inclusion_circles", "exclusion_circles"):
        for k, circle in enumerate(getattr(geofence, kind)):
            if circle.center_deg is not None:
                out.append(f"geofence.{kind}[{k}].center_deg")
    return out


def sitl_home(cfg: Any, path: str | None, environ: Any) -> Any:
    """``cfg`` with the home PX4 SITL would start at: the built-in configuration at PX4_SITL_HOME, any
    configuration moved by PX4_HOME_LAT / PX4_HOME_LON / PX4_HOME_ALT. ConfigError for a value that is not a
    number in range, and for moving the home of a configuration whose fence is in latitude/longitude."""
    from pydantic import ValidationError

    from merlin.config.loader import ConfigError
    from merlin.config.models import HomeConfig

    home = cfg.home.model_dump()
    if path is None:
        home.update(zip(("lat_deg", "lon_deg", "alt_amsl_m"), PX4_SITL_HOME, strict=True))
    set_by = []
    for var, fld in PX4_HOME_ENV:
        text = environ.get(var)
        if text is None or not text.strip():
            continue
        try:
            home[fld] = float(text)
        except ValueError:
            raise ConfigError(var, [f"{text!r} is not a number (home.{fld})"]) from None
        set_by.append(var)
    try:
        new_home = HomeConfig.model_validate(home)
    except ValidationError as err:
        e = err.errors()[0]
        where = next((v for v, f in PX4_HOME_ENV if f == e["loc"][0]), "home")
        raise ConfigError(where, [f"home.{e['loc'][0]} = {e['input']}: {e['msg']}"]) from None
    if new_home == cfg.home:
        return cfg
    fixed = _absolute_fence_fields(cfg.geofence)
    if fixed:
        why = ", ".join(set_by) or "the PX4 SITL default home"
        raise ConfigError(path or "<built-in default>", [
            f"{f} is in latitude/longitude: moving home to ({new_home.lat_deg:.6f}, {new_home.lon_deg:.6f}) by "
            f"{why} would leave the fence behind; give it about home (vertices_ne_m / center_ne_m) or keep the "
            "file's home" for f in fixed])
    return cfg.model_copy(update={"home": new_home})


def _vehicle_config(vehicle: str, path: str | None, cfg: Any) -> Any:
    """The configuration for ``--vehicle``: a fixed wing (JSBSim) flies the built-in fixed-wing configuration
    when no file is given, and refuses a configuration that is not a fixed wing's; a multirotor must exist."""
    from merlin.config.loader import ConfigError
    from sims.runner import FIXED_WING_VEHICLES, vehicle_params_path

    if vehicle in FIXED_WING_VEHICLES:
        from sims.fixedwing_loop import default_config

        if path is None:
            return default_config(vehicle)
        if cfg.vehicle.type.value != "fixed_wing":
            raise ConfigError(path, [f"vehicle.type: {cfg.vehicle.type.value!r}, but --vehicle {vehicle} is a fixed "
                                     "wing: its envelope and fence projection need vehicle.type: fixed_wing"])
        return cfg
    if not vehicle_params_path(vehicle).is_file():
        raise ConfigError("command line", [f"--vehicle {vehicle!r}: no such vehicle; allowed: a file in "
                                           f"sims/vehicles (without .yaml) or {', '.join(FIXED_WING_VEHICLES)}"])
    return cfg


def options_from_args(args: argparse.Namespace) -> Any:
    from merlin.config.loader import ConfigError
    from merlin.serve.link_security import KeyFileProblem, LinkOverrides, link_setups
    from merlin.serve.server import ServeOptions, UdpLinkSpec

    problems = []
    if not 0 <= args.instance <= 254:  # system id instance + 1 <= 255
        problems.append(f"--instance {args.instance}: allowed 0..254")
    else:
        for name, port in sitl_ports(args.instance).items():
            if getattr(args, name) is None:
                setattr(args, name, port)
        if args.sysid is None:
            args.sysid = args.instance + 1
    if not 100.0 <= args.rate_hz <= 1000.0:  # the simulation step (1/rate) is at most 10 ms
        problems.append(f"--rate-hz {args.rate_hz}: allowed 100..1000")
    else:
        from sims.scenario import period_problems

        problems += period_problems(1.0 / args.rate_hz, "1/--rate-hz", args.core_dt_s, args.nav_dt_s)
    if not 0.1 <= args.speedup <= 20.0:
        problems.append(f"--speedup {args.speedup}: allowed 0.1..20")
    if args.sysid is not None and not 1 <= args.sysid <= 255:
        problems.append(f"--sysid {args.sysid}: allowed 1..255")
    for name in ("gcs_port", "gcs_bind_port", "offboard_port", "offboard_bind_port"):
        v = getattr(args, name)
        if v is not None and not 0 <= v <= 65535:
            problems.append(f"--{name.replace('_', '-')} {v}: allowed 0..65535")
    if not 0 <= args.realtime_priority <= 99:
        problems.append(f"--realtime-priority {args.realtime_priority}: allowed 0..99")
    if args.duration is not None and not args.duration > 0:
        problems.append(f"--duration {args.duration}: must be > 0")
    serial = None
    if args.serial:
        dev, _, baud = args.serial.rpartition(":")
        if not dev or not baud.isdigit():
            problems.append(f"--serial {args.serial!r}: expected DEVICE:BAUD, e.g. /dev/ttyUSB0:921600")
        else:
            serial = (dev, int(baud))
    if problems:
        raise ConfigError("command line", problems)
    cfg, config_dir = _load(args.config)
    cfg = _vehicle_config(args.vehicle, args.config, cfg)  # the fixed wing's aircraft and limits
    cfg = sitl_home(cfg, args.config, os.environ)
    if args.autopilot_only:
        from merlin.serve.autopilot_only import autopilot_only

        cfg = autopilot_only(cfg)
    overrides = LinkOverrides(
        key_file=Path(args.signing_key) if args.signing_key else None,
        allow_unsigned_provisioning=args.allow_unsigned_provisioning,
        controller_system_ids=_ids(args.controller_sysids, "controller-sysids"),
        gcs_system_ids=_ids(args.gcs_sysids, "gcs-sysids"),
    )
    try:
        setups = link_setups(cfg.links, config_dir, overrides)
    except KeyFileProblem as exc:
        source = "command line" if exc.where.startswith("--") else (args.config or "<built-in default>")
        raise ConfigError(source, [str(exc)]) from None
    out = Path(args.out) if args.out else Path("out/serve") / dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    host = args.remote_host
    return ServeOptions(
        config=cfg, config_source=args.config or "<built-in default>", rate_hz=args.rate_hz, speedup=args.speedup,
        core_dt_s=_period(args.core_dt_s, args.rate_hz), nav_dt_s=_period(args.nav_dt_s, args.rate_hz),
        vehicle=args.vehicle,
        system_id=args.sysid, component_id=args.compid,
        gcs=None if args.no_gcs else UdpLinkSpec(("0.0.0.0", args.gcs_bind_port), (host, args.gcs_port)),
        controller=UdpLinkSpec(("0.0.0.0", args.offboard_bind_port), (host, args.offboard_port)),
        serial=serial, out_dir=out, duration_s=args.duration,
        controller_policy=setups["controller"].policy, gcs_policy=setups["gcs"].policy,
        controller_key_file=setups["controller"].key_file, gcs_key_file=setups["gcs"].key_file,
        tune_gc=not args.no_gc_tuning, realtime_priority=args.realtime_priority,
        params_locked=args.params_locked or cfg.links.params_locked,
    )


def _period(given: float | None, rate_hz: float) -> float:
    """A period option as flown: the one given, or the default's 10 ms rounded down to whole ticks."""
    from sims.scenario import default_period

    return given if given is not None else default_period(1.0 / rate_hz)


def preflight(cfg: Any, vehicle: str, source: str, accept_risk: list[str] | None, out_dir: Path,
              core_period_s: float = 0.0) -> Any:
    """The cross-checks (merlin.config.crosschecks) of the configuration to fly, against ``vehicle``: refuse
    (CrossCheckRefusal, exit 2) on an error not accepted by id; log every accepted error and warning, and
    write them to ``crosschecks.json`` beside the flight's logs, so the record says what was flown anyway."""
    from merlin.config.crosschecks import gate, parse_accept, run_checks
    from sims.runner import vehicle_capability

    result = gate(run_checks(cfg, vehicle=vehicle_capability(vehicle), core_period_s=core_period_s),
                  parse_accept(accept_risk), source)
    log = logging.getLogger("merlin.serve.crosschecks")
    for f in result.accepted:
        log.warning("risk accepted by --accept-risk: %s", f.line())
    for f in result.warnings:
        log.warning("%s", f.line())
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "crosschecks.json").write_text(
        json.dumps({"source": source, "vehicle": vehicle, **result.to_dict()}, indent=2) + "\n", encoding="utf-8")
    return result


def run(args: argparse.Namespace) -> int:
    from merlin.serve.server import Server, install_signal_handlers

    opts = options_from_args(args)
    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    preflight(opts.config, args.vehicle, opts.config_source, getattr(args, "accept_risk", None), opts.out_dir,
              float(cast(float, opts.core_dt_s)))
    server = Server(opts)
    install_signal_handlers(server)
    if not args.quiet:
        links = ", ".join(f"{ls.name}: {getattr(ls.endpoint.transport, 'local_address', '?')} -> "
                          f"{ls.endpoint.remote}" for ls in server.links)
        only = ", autopilot only (no geofence, no envelope, link or low-battery action)" if args.autopilot_only else ""
        periods = "".join(f", {name} every {float(cast(float, v)) * 1e3:g} ms"
                          for name, v in (("core", opts.core_dt_s), ("voter and filter", opts.nav_dt_s)))
        print(f"merlin serve: {opts.rate_hz:g} Hz{periods}{only}, {links}; logs in {opts.out_dir}", flush=True)
    summary = server.run()
    if not args.quiet:
        json.dump(summary["timing"], sys.stdout, indent=1)
        print(flush=True)
    return 0
