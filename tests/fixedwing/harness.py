"""A small closed loop for the fixed-wing tests: JSBSim at 400 Hz, Merlin's autopilot at 100 Hz.

The composition a runner would do: guidance, then the inner loops, then the surfaces held for four JSBSim
frames. ``observe`` sees every autopilot tick (truth, guidance status, control output).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from merlin.autopilot import fixedwing_control as fc
from merlin.autopilot import fixedwing_guidance as fg
from sims.fixedwing import FixedWingSim, FixedWingTruth

AUTOPILOT_HZ = 100.0
SIM_HZ = 400.0
FRAMES_PER_TICK = int(SIM_HZ / AUTOPILOT_HZ)


@dataclass
class Loop:
    sim: FixedWingSim
    cp: fc.FixedWingControlParams
    gp: fg.GuidanceParams
    gstate: fg.GuidanceState
    cstate: fc.FixedWingControlState

    @property
    def truth(self) -> FixedWingTruth:
        return self.sim.truth()

    def fly(
        self,
        duration_s: float,
        observe: Callable[[FixedWingTruth, fg.GuidanceStatus, fc.ControlOutput], bool | None] | None = None,
    ) -> None:
        """Fly under guidance for ``duration_s``; stop early if ``observe`` returns True."""
        dt = 1.0 / AUTOPILOT_HZ
        for _ in range(round(duration_s * AUTOPILOT_HZ)):
            vs = self.sim.truth().to_vehicle_state()
            self.gstate, targets, status = fg.guidance_step(self.gp, self.cp, self.gstate, vs)
            self.cstate, out = fc.control_step(self.cp, self.cstate, vs, targets, dt)
            truth = self.sim.advance(out.surfaces, FRAMES_PER_TICK)
            if observe is not None and observe(truth, status, out):
                return


def make_loop(
    *,
    pos_ned_m: tuple[float, float, float],
    heading_rad: float = 0.0,
    airspeed_mps: float = 22.0,
    wind_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Loop:
    """A trimmed aircraft with Merlin's autopilot taken over bumplessly, holding (loitering) until told."""
    sim = FixedWingSim(
        pos_ned_m=pos_ned_m,
        heading_rad=heading_rad,
        airspeed_mps=airspeed_mps,
        rate_hz=SIM_HZ,
        wind_ned_mps=wind_ned_mps,
    )
    cp = fc.FixedWingControlParams()
    gp = fg.GuidanceParams()
    vs = sim.truth().to_vehicle_state()
    assert sim.trim_result is not None
    cstate = fc.reset_from_state(cp, vs, sim.trim_result.surfaces)
    gstate = fg.start_hold(gp, cp, fg.GuidanceState(), vs)
    return Loop(sim, cp, gp, gstate, cstate)
