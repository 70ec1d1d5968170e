"""MAVSDK Action plugin flows against ``merlin serve``, on either MAVSDK-Python binding: the gRPC one
(``mavsdk_grpc``, MAVSDK-Python before 4) and the native ``mavsdk`` 4.x.

One flow, connected as a ground station would be (MAVSDK's default component type) on the link it is
given: ``set_takeoff_altitude`` then ``takeoff`` (MIS_TAKEOFF_ALT), ``set_current_speed``
(MAV_CMD_DO_CHANGE_SPEED) then ``goto_location`` (MAV_CMD_DO_REPOSITION, COMMAND_INT), ``do_orbit``
(MAV_CMD_DO_ORBIT), ``reboot`` (refused) and ``kill``. It prints what it measures, one ``FLOW <name>
<value>`` line each, and ``FLOW FINISHED`` at its end; an error ends it with a traceback.

Run: ``python -m tests.serve.mavsdk_action_flows grpc|native udpin://0.0.0.0:PORT [GRPC_PORT]``.
"""

from __future__ import annotations

import asyncio
import math
import sys
import time
from collections.abc import AsyncIterator
from typing import Any

TAKEOFF_ALT_M = 5.0
SPEED_MPS = 2.0
GOTO_NORTH_M = 40.0
ORBIT_RADIUS_M = 15.0
M_PER_DEG_LAT = 111_320.0


class Drone:
    """The calls the flow makes, on one binding."""

    def __init__(self, binding: str, handle: Any) -> None:
        self.binding = binding
        if binding == "grpc":
            self.action, self.telemetry = handle.action, handle.telemetry
        else:
            from mavsdk.asyncio.plugins.action import ActionAsync
            from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

            self.action, self.telemetry = ActionAsync(handle), TelemetryAsync(handle)

    def stream(self, name: str) -> AsyncIterator[Any]:
        if self.binding == "grpc":
            return getattr(self.telemetry, name)()  # type: ignore[no-any-return]
        return getattr(self.telemetry, f"subscribe_{name}")()  # type: ignore[no-any-return]

    async def first(self, name: str, pred: Any = None, timeout_s: float = 60.0) -> Any:
        async def loop() -> Any:
            async for v in self.stream(name):
                if pred is None or pred(v):
                    return v
            return None

        return await asyncio.wait_for(loop(), timeout_s)


def say(name: str, value: object) -> None:
    print(f"FLOW {name} {value}", flush=True)


async def flow(d: Drone) -> None:
    await d.first("health", lambda h: h.is_global_position_ok and h.is_home_position_ok)
    home = await d.first("home")
    await d.action.set_takeoff_altitude(TAKEOFF_ALT_M)
    say("takeoff_altitude_param", await d.action.get_takeoff_altitude())
    await d.action.arm()
    await d.action.takeoff()
    await d.first("position", lambda p: p.relative_altitude_m > TAKEOFF_ALT_M - 0.5)
    await asyncio.sleep(4.0)
    p = await d.first("position")
    say("altitude_after_takeoff_m", round(p.relative_altitude_m, 2))
    await d.action.set_current_speed(SPEED_MPS)
    lat = home.latitude_deg + GOTO_NORTH_M / M_PER_DEG_LAT
    t0 = time.monotonic()
    await d.action.goto_location(lat, home.longitude_deg, home.absolute_altitude_m + 8.0, 0.0)
    fastest = 0.0

    async def watch_speed() -> None:
        nonlocal fastest
        async for v in d.stream("velocity_ned"):
            fastest = max(fastest, math.hypot(v.north_m_s, v.east_m_s))

    speed_task = asyncio.ensure_future(watch_speed())

    def north_m(q: Any) -> float:
        return (q.latitude_deg - home.latitude_deg) * M_PER_DEG_LAT

    await d.first("position", lambda q: abs(north_m(q) - GOTO_NORTH_M) < 1.5, timeout_s=90)
    say("goto_reached_s", round(time.monotonic() - t0, 1))
    speed_task.cancel()
    say("goto_fastest_mps", round(fastest, 2))
    yaw_front = None
    if d.binding == "grpc":
        from mavsdk_grpc.action import OrbitYawBehavior

        yaw_front = OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER
    else:
        from mavsdk.asyncio.plugins.action import OrbitYawBehavior as NativeYaw

        yaw_front = NativeYaw.HOLD_FRONT_TO_CIRCLE_CENTER
    await d.action.do_orbit(ORBIT_RADIUS_M, SPEED_MPS, yaw_front, lat, home.longitude_deg,
                            home.absolute_altitude_m + 8.0)
    await asyncio.sleep(15.0)  # onto the circle
    dist = []
    t_end = time.monotonic() + 10.0
    async for q in d.stream("position"):
        dist.append(math.hypot(north_m(q) - GOTO_NORTH_M,
                               (q.longitude_deg - home.longitude_deg) * M_PER_DEG_LAT * math.cos(math.radians(lat))))
        if time.monotonic() > t_end:
            break
    say("orbit_radius_min_m", round(min(dist), 2))
    say("orbit_radius_max_m", round(max(dist), 2))
    try:
        await d.action.reboot()
        say("reboot", "accepted")
    except Exception as exc:  # the binding's ActionError: UNSUPPORTED
        say("reboot", type(exc).__name__ + ":" + str(exc).replace(" ", "_")[:60])
    await d.action.kill()
    await d.first("armed", lambda a: not a, timeout_s=10)
    say("killed", True)


async def main(binding: str, url: str, grpc_port: int) -> None:
    if binding == "grpc":
        from mavsdk_grpc import System

        drone = System(port=grpc_port)
        await drone.connect(system_address=url)
        await flow(Drone("grpc", drone))
    else:
        from mavsdk.asyncio import ComponentType, Configuration, Mavsdk

        config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)  # MAVSDK's default
        async with Mavsdk(config) as mavsdk:
            await mavsdk.add_any_connection(url)
            system = await mavsdk.first_autopilot(timeout_s=60.0)
            if system is None:
                raise SystemExit("no autopilot found")
            await flow(Drone("native", system))
    print("FLOW FINISHED", flush=True)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else 50051))
