"""The fixed wing's stall recovery from any state the envelope hands over: height lost against the bound.

Flies ``examples/scenarios/fw_stall_protection.yaml`` (the Aerosonde under ``fixedwing_default.yaml``, 160 m)
with the adversary :class:`experimental_controllers.fixedwing_examples.PullUpPush` drawn at random: a
pull-up (1-6 deg/s to 20-40 deg at 0-0.3 throttle, banked up to 40 deg), then, just before the airspeed
revocation (0-0.45 s after the airspeed fell below 18.5 m/s; one run in five never pushes), the nose pushed
down to -20..0 deg at full or random throttle and up to 45 deg of bank, in a random steady wind (sigma
2 m/s per axis). For each run: the state at the revocation (pitch, pitch rate, bank, throttle, airspeed,
sink), the surfaces handed over and the inner loops' integrators and setpoints that produced them, and the
height lost after it (the ``max_height_loss_after_revocation`` measure), the lowest airspeed
and the highest angle of attack after it, the largest bank Merlin flew.

``--direct N`` adds a sweep of N states drawn uniformly from the box the envelope allows at a revocation
(airspeed 16-33 m/s, angle of attack -8..17 deg, pitch -30..30 deg with the sink within +-8 m/s, bank
+-45 deg, body rates within the envelope's +-150/90/90 deg/s, any throttle; ``--surfaces any``: any
surface deflection; ``--surfaces loops``, the default: the deflections Merlin's inner loops command in that
state for some authority's command, which is what every authority is flown through, :func:`loop_surfaces`;
``--corners``: every quantity at an end of its range), set directly in
JSBSim (:meth:`sims.fixedwing.FixedWingSim.set_flight_state`) and handed to Merlin's actuator stage
(:class:`merlin.autopilot.fixedwing_behaviours.FixedWingBehaviours`) flying RTL for 20 s: the states an
adversary could reach by means this closed loop's inner loops would not let it (a controller driving the
surfaces itself, or a disturbance). For each: the height lost, and how fast the loops' own elevator and
aileron commands moved once the takeover slew had ended while the recovery flew (the measure of "the
trusted controller's own slew" in an upset, which the recovery's takeover slew stays within).

The bound it is checked against is :func:`merlin.autopilot.fixedwing_recovery.recovery_height_bound_m`,
derived from the aircraft model and the envelope (its docstring), so the benchmark reports the worst loss
found, the bound, and the minimum grant height
(:func:`merlin.autopilot.fixedwing_recovery.min_grant_height_m`) for the configuration.

    MERLIN_USE_SOURCES=1 .venv/bin/python benchmarks/bench_fw_recovery.py --runs 60 --direct 150 --seed 1
    MERLIN_USE_SOURCES=1 .venv/bin/python benchmarks/bench_fw_recovery.py --runs 0 --direct 150 --surfaces any
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from merlin.autopilot import fixedwing_control as fc  # noqa: E402
from merlin.autopilot import fixedwing_guidance as fg  # noqa: E402
from merlin.autopilot import fixedwing_recovery as rec  # noqa: E402
from merlin.autopilot.fixedwing_behaviours import FixedWingBehaviours  # noqa: E402
from merlin.config.runtime import build_core_config  # noqa: E402
from merlin.core.types import Authority, Behavior, Command, CommandKind, Decision, VehicleState  # noqa: E402
from sims.fixedwing import FixedWingSim, SurfaceCommand  # noqa: E402
from sims.runner import make_loop, run_scenario  # noqa: E402
from sims.scenario import load_scenario  # noqa: E402

SCENARIO = ROOT / "examples" / "scenarios" / "fw_stall_protection.yaml"
CONTROLLER = "experimental_controllers.fixedwing_examples:PullUpPush"


def draw(rng: np.random.Generator) -> tuple[dict[str, float], tuple[float, float, float]]:
    """One adversary and one steady wind."""
    params = {
        "request_at_s": 1.0, "start_after_s": 1.0,
        "pitch_rate_degps": float(rng.uniform(1.0, 6.0)), "max_pitch_deg": float(rng.uniform(20.0, 40.0)),
        "throttle": float(rng.uniform(0.0, 0.3)), "roll_deg": float(rng.uniform(-40.0, 40.0)),
        "push_after_s": float(rng.uniform(0.0, 0.45)) if rng.random() > 0.2 else 99.0,
        "push_pitch_deg": float(rng.uniform(-20.0, 0.0)),
        "push_throttle": 1.0 if rng.random() < 0.6 else float(rng.uniform(0.0, 1.0)),
        "push_roll_deg": float(rng.uniform(-45.0, 45.0)),
    }
    wind = (float(rng.normal(0.0, 2.0)), float(rng.normal(0.0, 2.0)), 0.0)
    return params, wind


class _WatchedStage:
    """The loop's actuator stage, seen through: :meth:`step` notes the first tick Merlin flies after the
    experimental controller, everything else goes to the stage. A wrapper, not an instance attribute over
    ``step``: the stage is a compiled (mypyc) class in the compiled build, whose methods cannot be
    replaced on an instance."""

    def __init__(self, stage: Any, loops: list[dict[str, float]]) -> None:
        object.__setattr__(self, "_stage", stage)
        object.__setattr__(self, "_loops", loops)
        object.__setattr__(self, "_seen_experimental", False)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stage, name)

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self._stage, name, value)

    def step(self, t: float, decision: Decision, s: Any, takeoff_height_m: float) -> SurfaceCommand:
        stage = self._stage
        if decision.authority is Authority.EXPERIMENTAL:
            object.__setattr__(self, "_seen_experimental", True)
        elif self._seen_experimental and not self._loops:
            c, cp = stage.cstate, stage.cp
            self._loops.append({"t": t, "elevator": stage.surfaces.elevator, "aileron": stage.surfaces.aileron,
                                "rudder": stage.surfaces.rudder,
                                "elevator_integ_from_trim": c.elevator_integ - cp.elevator_trim,
                                "aileron_integ": c.aileron_integ, "rudder_integ": c.rudder_integ,
                                "pitch_sp_deg": math.degrees(c.pitch_sp_rad),
                                "roll_sp_deg": math.degrees(c.roll_sp_rad)})
        return stage.step(t, decision, s, takeoff_height_m)  # type: ignore[no-any-return]


def _watched_loop(sc: Any, cfg: Any, loops: list[dict[str, float]]) -> Any:
    """The scenario's vehicle side (a FixedWingLoop: the scenario is the fixed wing's) with its actuator
    stage wrapped: at the first tick Merlin flies after the experimental controller, the wrapper notes the
    surfaces handed over and the inner loops' state that produced them (their integrators and setpoints)."""
    loop: Any = make_loop(sc, cfg)
    loop.stage = _WatchedStage(loop.stage, loops)
    return loop


def fly(params: dict[str, float], wind: tuple[float, float, float]) -> dict[str, float] | None:
    """One run; None when the envelope never revoked (nothing to recover from)."""
    sc, cfg = load_scenario(SCENARIO)
    sc = sc.model_copy(update={
        "controller": sc.controller.model_copy(update={"type": CONTROLLER, "params": params}),
        "wind": sc.wind.model_copy(update={"steady_ned_mps": list(wind)}),
        "expectations": [],
    })
    handover: list[dict[str, float]] = []
    r = run_scenario(sc, cfg, loop=_watched_loop(sc, cfg, handover))
    revs = [e for e in r.events if e["type"] == "revoked"]
    if not revs:
        return None
    a = r.log
    t0 = float(revs[0]["t"])
    k = min(int(np.searchsorted(a["t"], t0 - 1e-9)), len(a["t"]) - 1)
    h = -np.asarray(a["truth_d"], dtype=float)
    excursions = [e for e in r.events if e["type"] == "fixed_wing_trusted_excursion"]
    return {
        "t_rev_s": t0, "reason": revs[0]["reason_detail"]["parameter"],
        "pitch_deg": math.degrees(a["truth_pitch"][k]), "pitch_rate_degps": float(a["env_pitch_rate_degps"][k]),
        "roll_deg": math.degrees(a["truth_roll"][k]), "throttle": float(a["m3"][max(k - 1, 0)]),
        "airspeed_mps": float(a["env_airspeed_mps"][k]), "sink_mps": float(a["truth_vd"][k]),
        "loss_m": float(h[k] - h[k:].min()),
        "min_airspeed_after_mps": float(a["env_airspeed_mps"][k:].min()),
        "max_alpha_after_deg": float(a["env_alpha_deg"][k:].max()),
        "max_bank_after_deg": float(np.degrees(np.abs(a["truth_roll"][k:])).max()),
        "excursions": float(len(excursions)),
        **{f"handover_{k}": v for k, v in (handover[0] if handover else {}).items()},
    }


def loop_surfaces(st: dict[str, float], rng: np.random.Generator, band: float) -> dict[str, float]:
    """The surfaces Merlin's inner loops command in the state ``st`` for some authority's command: the attitude
    setpoints anywhere within the loops' own limits (pitch +-20 deg, the bank limit), the integrators within
    ``band`` of their trim, the rate damping of the state's body rates (what every authority is flown
    through: there is no surface setpoint)."""
    cp = fc.FixedWingControlParams()
    roll, pitch = math.radians(st["roll_deg"]), math.radians(st["pitch_deg"])
    v = st["airspeed_mps"]
    gamma = pitch - math.radians(st["alpha_deg"]) * math.cos(roll)
    s = VehicleState(vel_ned_mps=(v * math.cos(gamma), 0.0, -v * math.sin(gamma)), att_rpy_rad=(roll, pitch, 0.0),
                     rates_frd_radps=(math.radians(st["p_degps"]), math.radians(st["q_degps"]),
                                      math.radians(st["r_degps"])),
                     airspeed_mps=v, armed=True, landed=False)
    pitch_sp = float(rng.uniform(cp.pitch_min_rad, cp.pitch_max_rad))
    roll_sp = float(rng.uniform(-fc.bank_limit_rad(cp), fc.bank_limit_rad(cp)))
    state = fc.FixedWingControlState(
        roll_sp_rad=roll_sp, pitch_sp_rad=pitch_sp, throttle=st["throttle"], initialized=True,
        aileron_integ=float(rng.uniform(-band, band)), rudder_integ=float(rng.uniform(-band, band)),
        elevator_integ=cp.elevator_trim + float(rng.uniform(-band, band)))
    targets = fc.FixedWingTargets(airspeed_mps=v, height_m=None, roll_rad=roll_sp, pitch_rad=pitch_sp,
                                  throttle=st["throttle"])
    _, out = fc.control_step(cp, state, s, targets, 0.01)
    return {"aileron": out.surfaces.aileron, "elevator": out.surfaces.elevator, "rudder": out.surfaces.rudder}


class _Ends:
    """Draws at either end of each range (the box's corners), with the generator's own coin."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def uniform(self, lo: float, hi: float) -> float:
        return lo if self.rng.random() < 0.5 else hi

    def random(self) -> float:
        return float(self.rng.random())


def direct_states(n: int, rng: np.random.Generator, surfaces: str = "any", band: float = 0.5,
                  corners: bool = False) -> list[dict[str, float]]:
    """``n`` states drawn uniformly from the envelope's box (module docstring), the sink within +-8 m/s;
    ``surfaces`` "loops": the surfaces the inner loops would command there (:func:`loop_surfaces`), "any":
    any deflection; ``corners``: every quantity at one end of its range."""
    rng = _Ends(rng) if corners else rng  # type: ignore[assignment]
    out: list[dict[str, float]] = []
    while len(out) < n:
        st = {"airspeed_mps": float(rng.uniform(16.0, 33.0)), "alpha_deg": float(rng.uniform(-8.0, 17.0)),
              "pitch_deg": float(rng.uniform(-30.0, 30.0)), "roll_deg": float(rng.uniform(-45.0, 45.0)),
              "p_degps": float(rng.uniform(-150.0, 150.0)), "q_degps": float(rng.uniform(-90.0, 90.0)),
              "r_degps": float(rng.uniform(-90.0, 90.0)), "throttle": float(rng.uniform(0.0, 1.0)),
              "aileron": float(rng.uniform(-1.0, 1.0)), "elevator": float(rng.uniform(-1.0, 1.0)),
              "rudder": float(rng.uniform(-1.0, 1.0))}
        gamma = math.radians(st["pitch_deg"]) - math.radians(st["alpha_deg"]) * math.cos(math.radians(st["roll_deg"]))
        if abs(st["airspeed_mps"] * math.sin(gamma)) <= 8.0:
            if surfaces == "loops":
                st.update(loop_surfaces(st, rng, band))
            out.append(st)
    return out


def fly_direct(sim: FixedWingSim, st: dict[str, float], cfg: object, envelope: tuple, duration_s: float = 20.0,
               rate_hz: float = 100.0) -> dict[str, float]:
    """Hand the state to Merlin's stage flying RTL; the height lost, the lowest airspeed, highest alpha."""
    cp = fc.FixedWingControlParams()
    gp = fg.GuidanceParams()
    surfaces = SurfaceCommand(st["aileron"], st["elevator"], st["rudder"], st["throttle"])
    tr = sim.set_flight_state(pos_ned_m=(0.0, 0.0, -160.0), heading_rad=0.0, airspeed_mps=st["airspeed_mps"],
                              alpha_rad=math.radians(st["alpha_deg"]), pitch_rad=math.radians(st["pitch_deg"]),
                              roll_rad=math.radians(st["roll_deg"]),
                              rates_frd_radps=(math.radians(st["p_degps"]), math.radians(st["q_degps"]),
                                               math.radians(st["r_degps"])), surfaces=surfaces)
    frames = round(sim.rate_hz / rate_hz)
    dt = frames / sim.rate_hz
    vs = tr.to_vehicle_state()
    stage = FixedWingBehaviours(None, cp, gp, (), surfaces, vs, 1, dt, envelope=envelope)
    decision = Decision(0.0, Authority.TRUSTED, Behavior.RTL, Command(CommandKind.VELOCITY, Authority.TRUSTED),
                        (), (), True)
    h0 = tr.alt_m
    h_min, v_min, a_max, bank_max = h0, tr.airspeed_mps, tr.alpha_rad, 0.0
    crashed = False
    own_prev: tuple[float, float] | None = None
    own_rate = 0.0
    for k in range(round(duration_s * rate_hz)):
        vs = replace(tr.to_vehicle_state(), alpha_rad=tr.alpha_rad)  # the alpha vane, as the closed loop's
        out = stage.step(k * dt, decision, vs, 0.0)
        # the loops' own commands (the takeover slew over) while the recovery flies, in the first 3 s
        if stage.cstate.handover is None and stage.cstate.recovering and k * dt < 3.0:
            if own_prev is not None:
                own_rate = max(own_rate, abs(out.elevator - own_prev[0]) / dt, abs(out.aileron - own_prev[1]) / dt)
            own_prev = (out.elevator, out.aileron)
        else:
            own_prev = None
        tr = sim.advance(out, frames)
        h_min, v_min, a_max = min(h_min, tr.alt_m), min(v_min, tr.airspeed_mps), max(a_max, tr.alpha_rad)
        if k * dt >= 3.0:
            bank_max = max(bank_max, abs(tr.rpy_rad[0]))
        crashed = crashed or not math.isfinite(tr.alt_m)
    excursions = [e for e in stage.notes if e["type"] == "fixed_wing_trusted_excursion"]
    return {"loss_m": h0 - h_min, "min_airspeed_mps": v_min, "max_alpha_deg": math.degrees(a_max),
            "max_bank_after_3s_deg": math.degrees(bank_max), "excursions": float(len(excursions)),
            "final_airspeed_mps": tr.airspeed_mps, "own_rate_per_s": own_rate}


def run_direct(n: int, rng: np.random.Generator, cfg: object, surfaces: str = "any", band: float = 0.5,
               corners: bool = False) -> list[tuple[dict[str, float], dict[str, float]]]:
    sim = FixedWingSim(pos_ned_m=(0.0, 0.0, -160.0), rate_hz=400.0)
    envelope = build_core_config(cfg).envelope  # type: ignore[arg-type]
    rows = []
    for i, st in enumerate(direct_states(n, rng, surfaces, band, corners)):
        res = fly_direct(sim, st, cfg, envelope)
        rows.append((st, res))
        print(f"state {i:3d}: V {st['airspeed_mps']:5.1f} alpha {st['alpha_deg']:5.1f} pitch {st['pitch_deg']:6.1f}"
              f" bank {st['roll_deg']:6.1f} q {st['q_degps']:6.1f} throttle {st['throttle']:4.2f}"
              f" elevator {st['elevator']:5.2f} -> lost {res['loss_m']:5.2f} m, min airspeed"
              f" {res['min_airspeed_mps']:5.2f}, max alpha {res['max_alpha_deg']:5.1f}, bank after 3 s"
              f" {res['max_bank_after_3s_deg']:5.1f}", flush=True)
    return rows


def grid_states(cfg: object) -> tuple[list[dict[str, float]], np.ndarray]:
    """The entry states the derived bound is taken over (:func:`merlin.autopilot.fixedwing_recovery.
    entry_states`: the box's corners in angle of attack, pitch rate, bank and roll rate, surfaces and
    throttle, over a grid of airspeeds and sinks), as direct states, and the model's height lost for each."""
    cp = fc.FixedWingControlParams()
    e = rec.entry_states(rec.AEROSONDE, *rec._limits(cfg, cp))  # type: ignore[arg-type]
    model = rec.height_lost_m(rec.AEROSONDE, rec.AEROSONDE_MOMENTS, rec.AEROSONDE_PROPULSION, cp, e)
    out = []
    for k in range(len(e.airspeed_mps)):
        v, sink, alpha, phi = (float(e.airspeed_mps[k]), float(e.sink_mps[k]), float(e.alpha_rad[k]),
                               float(e.bank_rad[k]))
        gamma = -math.asin(sink / v)
        out.append({"airspeed_mps": v, "alpha_deg": math.degrees(alpha),
                    "pitch_deg": math.degrees(gamma + alpha * math.cos(phi)), "roll_deg": math.degrees(phi),
                    "p_degps": math.degrees(float(e.p_radps[k])), "q_degps": math.degrees(float(e.q_radps[k])),
                    "r_degps": 0.0, "throttle": float(e.throttle[k]), "aileron": float(e.aileron[k]),
                    "elevator": float(e.elevator[k]), "rudder": 0.0, "sink_mps": sink})
    return out, model


def run_grid(cfg: object, throttle: float | None = None) -> list[tuple[dict[str, float], dict[str, float]]]:
    """Every state of the bound's grid flown in JSBSim (:func:`grid_states`), beside the model's loss; with
    ``throttle``, only the states handed over at that throttle (half the grid: a recovery from a slow state
    goes to full power at once, so the two halves lose nearly alike)."""
    sim = FixedWingSim(pos_ned_m=(0.0, 0.0, -160.0), rate_hz=400.0)
    envelope = build_core_config(cfg).envelope  # type: ignore[arg-type]
    states, model = grid_states(cfg)
    rows = []
    for i, (st, m) in enumerate(zip(states, model, strict=True)):
        if throttle is not None and st["throttle"] != throttle:
            continue
        res = fly_direct(sim, st, cfg, envelope)
        res["model_m"] = float(m)
        rows.append((st, res))
        print(f"grid {i:4d}: V {st['airspeed_mps']:5.1f} sink {st['sink_mps']:5.1f} alpha {st['alpha_deg']:5.1f}"
              f" q {st['q_degps']:6.1f} bank {st['roll_deg']:5.1f} p {st['p_degps']:6.1f} elevator"
              f" {st['elevator']:5.2f} aileron {st['aileron']:5.2f} throttle {st['throttle']:4.2f} -> lost"
              f" {res['loss_m']:5.2f} m (model {m:5.2f} m)", flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=120)
    ap.add_argument("--direct", type=int, default=0, help="states set directly in JSBSim (module docstring)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--surfaces", choices=("loops", "any"), default="loops",
                    help="the direct states' surfaces: the inner loops' own command there, or any deflection")
    ap.add_argument("--band", type=float, default=0.5,
                    help="with --surfaces loops: the integrators' spread about trim")
    ap.add_argument("--corners", action="store_true", help="the direct states at the box's corners")
    ap.add_argument("--grid", action="store_true",
                    help="fly every entry state of the derived bound's grid in JSBSim, beside the model's loss")
    ap.add_argument("--grid-throttle", type=float, default=None,
                    help="with --grid, only the states handed over at this throttle (0 or 1)")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    _, cfg = load_scenario(SCENARIO)
    bound = rec.recovery_height_bound_m(cfg)
    direct_ok = True
    if args.grid:
        grows = run_grid(cfg, args.grid_throttle)
        gl = np.array([r["loss_m"] for _, r in grows])
        gm = np.array([r["model_m"] for _, r in grows])
        worst_st = grows[int(np.argmax(gl))][0]
        print(f"\ngrid: {len(grows)} states; height lost median {np.median(gl):.2f} m, p95 {np.percentile(gl, 95):.2f}"
              f" m, worst {gl.max():.2f} m at {worst_st}; the model's worst {gm.max():.2f} m (the bound);"
              f" states over the bound {int((gl > bound).sum())}; states the model under-predicts by more than"
              f" 0.5 m: {int((gl > gm + 0.5).sum())} (largest {float((gl - gm).max()):.2f} m, at a loss of"
              f" {float(gl[int(np.argmax(gl - gm))]):.2f} m)\n")
        direct_ok = bool(gl.max() <= bound)
    if args.direct:
        drows = run_direct(args.direct, np.random.default_rng(args.seed + 1000), cfg, args.surfaces, args.band,
                           args.corners)
        dl = np.array([r["loss_m"] for _, r in drows])
        worst_st = drows[int(np.argmax(dl))][0]
        print(f"\ndirect ({args.surfaces} surfaces{', corners' if args.corners else ''}): {len(drows)} states; height lost median {np.median(dl):.2f} m, p95"
              f" {np.percentile(dl, 95):.2f} m, worst {dl.max():.2f} m at {worst_st}")
        print(f"direct: lowest airspeed {min(r['min_airspeed_mps'] for _, r in drows):.2f} m/s, highest alpha"
              f" {max(r['max_alpha_deg'] for _, r in drows):.1f} deg, largest bank after 3 s"
              f" {max(r['max_bank_after_3s_deg'] for _, r in drows):.1f} deg; final airspeed"
              f" {min(r['final_airspeed_mps'] for _, r in drows):.1f}..{max(r['final_airspeed_mps'] for _, r in drows):.1f}"
              f" m/s; derived bound {bound:.2f} m; states over it {int((dl > bound).sum())}")
        own = np.array([r["own_rate_per_s"] for _, r in drows if r["own_rate_per_s"] > 0.0])
        if own.size:
            print(f"direct: the loops' own elevator/aileron command rate in the recovery ({own.size} states):"
                  f" median {np.median(own):.1f} /s, p10 {np.percentile(own, 10):.1f} /s, max {own.max():.1f} /s"
                  f" (the recovery's takeover slew {fc.FixedWingControlParams().recovery_takeover_slew_per_s:.1f} /s)\n")
        direct_ok = bool(dl.max() <= bound)
    rows = []
    t0 = time.perf_counter()
    for i in range(args.runs):
        params, wind = draw(rng)
        row = fly(params, wind)
        if row is None:
            print(f"run {i:3d}: no revocation", flush=True)
            continue
        rows.append(row)
        print(f"run {i:3d}: {row['reason']:>13s} pitch {row['pitch_deg']:6.1f} deg  q {row['pitch_rate_degps']:6.1f}"
              f" deg/s  bank {row['roll_deg']:6.1f} deg  throttle {row['throttle']:4.2f}  airspeed"
              f" {row['airspeed_mps']:5.2f} m/s  sink {row['sink_mps']:5.2f} m/s -> lost {row['loss_m']:5.2f} m,"
              f" min airspeed {row['min_airspeed_after_mps']:5.2f}, max alpha {row['max_alpha_after_deg']:5.1f},"
              f" max bank {row['max_bank_after_deg']:5.1f}", flush=True)
    if not args.runs:
        return 0 if direct_ok else 1
    if not rows:
        print("no run revoked")
        return 1
    def span(key: str, among: list[dict[str, float]] | None = None) -> str:
        v = [r[key] for r in (rows if among is None else among)]
        nd = 1 if key.endswith(("_deg", "_degps", "_mps", "_m")) else 2
        return f"{min(v):.{nd}f} .. {max(v):.{nd}f}"
    losses = np.array([r["loss_m"] for r in rows])
    worst = rows[int(np.argmax(losses))]
    print(f"\n{len(rows)} revoked runs of {args.runs} ({time.perf_counter() - t0:.0f} s)")
    print(f"states at the revocation: pitch {span('pitch_deg')} deg, pitch rate {span('pitch_rate_degps')} deg/s,"
          f" bank {span('roll_deg')} deg, throttle {span('throttle')}, airspeed {span('airspeed_mps')} m/s,"
          f" sink {span('sink_mps')} m/s")
    print(f"height lost: median {np.median(losses):.2f} m, p95 {np.percentile(losses, 95):.2f} m,"
          f" worst {losses.max():.2f} m (pitch {worst['pitch_deg']:.1f}, q {worst['pitch_rate_degps']:.1f},"
          f" airspeed {worst['airspeed_mps']:.2f}, sink {worst['sink_mps']:.2f})")
    ho = [r for r in rows if "handover_elevator" in r]
    if ho:
        print(f"at the handover ({len(ho)} runs, the loops' state under the experimental command): elevator"
              f" {span('handover_elevator', ho)}, aileron {span('handover_aileron', ho)}, rudder {span('handover_rudder', ho)};"
              f" integrators: elevator - trim {span('handover_elevator_integ_from_trim', ho)}, aileron"
              f" {span('handover_aileron_integ', ho)}, rudder {span('handover_rudder_integ', ho)}; setpoints: pitch"
              f" {span('handover_pitch_sp_deg', ho)} deg, roll {span('handover_roll_sp_deg', ho)} deg")
    print(f"after the revocation: lowest airspeed {span('min_airspeed_after_mps')} m/s, highest alpha"
          f" {span('max_alpha_after_deg')} deg, largest bank {span('max_bank_after_deg')} deg,"
          f" trusted excursions {int(sum(r['excursions'] for r in rows))}")
    print(f"derived bound {bound:.2f} m;"
          f" minimum grant height {rec.min_grant_height_m(cfg):.2f} m above home")
    return 0 if losses.max() <= bound and direct_ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
