"""How much height the fixed wing's recovery can lose, derived from the aircraft and the envelope, and the
lowest height at which handing authority to an experimental controller keeps the floor.

When the trusted core takes authority back from an experimental controller, Merlin's inner loops
(:func:`merlin.autopilot.fixedwing_control.control_step`) recover: below the minimum airspeed they fly
full power at once, wings level, and pitch on the sink alone up to the angle-of-attack cap, until the
airspeed is back above the minimum and the sink is arrested. :func:`recovery_height_bound_m` bounds the
height that costs from any state the envelope lets the controller hand over, with a point-mass model of
the aircraft that is conservative by construction:

* the state at the revocation: any airspeed from the 1 g stall speed ``V_s`` to the envelope's maximum,
  any sink up to the envelope's ``vel_d_mps`` maximum, and the lowest angle of attack the envelope allows
  (``alpha_deg`` minimum: the controller was pushing), with the pitch (flight path plus angle of attack,
  wings level) within the envelope's ``pitch_deg`` minimum;
* the wing: the model's linear lift curve ``C_L = C_L0 + C_La alpha`` (Beard and McLain 2012, App. E.2,
  the Aerosonde of ``sims/aircraft/aerosonde``), load factor ``n = q S C_L / W`` capped at the autopilot's
  load-factor limit;
* the recovery: the angle of attack ramps from the revocation's to the cap at the pitch setpoint's slew
  rate (the pitch loop's lag is in the measured margin), wings level;
* no thrust and no drag: at full power the Aerosonde's thrust exceeds its drag over the recovery's speeds
  (it trims at full power up to 32 m/s and climbs at about 6 m/s at 22 m/s), so leaving both out only adds
  height lost to speed;
* the recovery ends when the flight path is level again and the wing at the cap holds 1 g.

The bound is the worst height lost over a grid of those states (``dV/dt = -g sin(gamma)``,
``dgamma/dt = g (n - cos(gamma)) / V``, ``dh/dt = V sin(gamma)``, integrated at 10 ms).
``benchmarks/bench_fw_recovery.py`` checks it against the closed loop (JSBSim) over adversaries that pull up
and push down at every rate, throttle and bank the envelope lets through; ``fw_adv_push_before_stall_*``
are the regression scenarios.

:func:`min_grant_height_m` adds the bound to the floor (the fence floor plus its margin, or the envelope's
altitude minimum, whichever is higher): a revocation at or above that height recovers above the floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from merlin.autopilot.fixedwing_control import FixedWingControlParams
from merlin.config.models import MerlinConfig

G_MPS2 = 9.80665
RHO_SEA_LEVEL_KGPM3 = 1.225


@dataclass(frozen=True, slots=True)
class WingModel:
    """The lift side of the aircraft model."""

    mass_kg: float
    wing_area_m2: float
    cl0: float
    cl_alpha_per_rad: float
    cl_max: float
    rho_kgpm3: float = RHO_SEA_LEVEL_KGPM3

    def load_factor(self, airspeed_mps: float, alpha_rad: float) -> float:
        cl = min(self.cl0 + self.cl_alpha_per_rad * alpha_rad, self.cl_max)
        return 0.5 * self.rho_kgpm3 * airspeed_mps**2 * self.wing_area_m2 * cl / (self.mass_kg * G_MPS2)

    def stall_speed_mps(self) -> float:
        """The 1 g stall speed."""
        return math.sqrt(2.0 * self.mass_kg * G_MPS2 / (self.rho_kgpm3 * self.wing_area_m2 * self.cl_max))


#: The Aerosonde (Beard and McLain 2012, App. E.2; sims/aircraft/aerosonde_envelope.yaml): 13.5 kg,
#: 0.55 m^2, C_L = 0.28 + 3.45 alpha, C_L,max 1.63 at 23.5 deg (V_s = 15.5 m/s).
AEROSONDE = WingModel(mass_kg=13.5, wing_area_m2=0.55, cl0=0.28, cl_alpha_per_rad=3.45, cl_max=1.63)

_DT_S = 0.01
_MAX_S = 60.0


def _height_lost_m(wing: WingModel, cp: FixedWingControlParams, v0: float, sink0: float, alpha0: float) -> float:
    """Height lost by the point-mass recovery from airspeed ``v0``, sink ``sink0`` (m/s, down positive) and
    angle of attack ``alpha0`` (module docstring)."""
    v = v0
    gamma = -math.asin(min(sink0 / v0, 1.0))
    h = h_min = 0.0
    alpha_cap = cp.alpha_protect_rad
    ramp = cp.pitch_sp_rate_radps
    t = 0.0
    while t < _MAX_S:
        alpha = min(alpha0 + ramp * t, alpha_cap)
        n = min(wing.load_factor(v, alpha), cp.load_factor_max)
        if gamma >= 0.0 and alpha >= alpha_cap and wing.load_factor(v, alpha_cap) >= 1.0:
            return -h_min
        v = max(v - G_MPS2 * math.sin(gamma) * _DT_S, 1.0)
        gamma += G_MPS2 * (n - math.cos(gamma)) / v * _DT_S
        h += v * math.sin(gamma) * _DT_S
        h_min = min(h_min, h)
        t += _DT_S
    return math.inf


def recovery_height_bound_m(cfg: MerlinConfig, wing: WingModel = AEROSONDE,
                            cp: FixedWingControlParams | None = None) -> float:
    """The most height the recovery can lose from any state the configuration's envelope hands over
    (module docstring). Without an envelope airspeed or sink limit, the stall speed and 8 m/s are assumed."""
    cp = FixedWingControlParams() if cp is None else cp
    stage = cfg.envelope.stages[cfg.envelope.active_stage]
    airspeed = getattr(stage, "airspeed_mps", None)
    v_max = float(airspeed.max) if airspeed is not None and airspeed.enabled else cp.airspeed_max_mps
    vel_d = getattr(stage, "vel_d_mps", None)
    sink_max = float(vel_d.max) if vel_d is not None and vel_d.enabled else 8.0
    alpha = getattr(stage, "alpha_deg", None)
    alpha_min = math.radians(float(alpha.min)) if alpha is not None and alpha.enabled else 0.0
    pitch = getattr(stage, "pitch_deg", None)
    pitch_min = math.radians(float(pitch.min)) if pitch is not None and pitch.enabled else -math.pi / 2
    v_s = wing.stall_speed_mps()
    worst = 0.0
    for i in range(13):
        v0 = v_s + (v_max - v_s) * i / 12
        for j in range(9):
            # the steepest descent the pitch limit allows at this angle of attack
            sink0 = min(sink_max * j / 8, v0 * math.sin(min(alpha_min - pitch_min, 0.5 * math.pi)))
            worst = max(worst, _height_lost_m(wing, cp, v0, sink0, alpha_min))
    return worst


def min_grant_height_m(cfg: MerlinConfig, wing: WingModel = AEROSONDE,
                       cp: FixedWingControlParams | None = None) -> float:
    """The lowest height above home at which a revocation still recovers above the floor: the floor (the
    fence floor plus its margin, or the envelope's altitude minimum, whichever is higher; 0 without
    either) plus :func:`recovery_height_bound_m`."""
    floors = [0.0]
    fence = cfg.geofence
    if fence.enabled and fence.altitude_floor_m is not None:
        floors.append(float(fence.altitude_floor_m) + float(fence.margin_m))
    stage = cfg.envelope.stages[cfg.envelope.active_stage]
    altitude = getattr(stage, "altitude_m", None)
    if altitude is not None and altitude.enabled:
        floors.append(float(altitude.min))
    return max(floors) + recovery_height_bound_m(cfg, wing, cp)
