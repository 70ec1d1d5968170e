"""MAVSDK-Python's example programs, as a user runs them against PX4 SITL, written for the project.

Each program makes the calls of the example of the same name in MAVSDK-Python's ``examples/`` folder
(mavlink/MAVSDK-Python), in the same order and with the same waits, and uses its hard-coded coordinates
(PX4 SITL's default home, Zurich). The flows are written once, against the gRPC MAVSDK-Python's API
(``mavsdk_grpc``, ``mavsdk<4``): the binding's types and error codes come from a :class:`Binding`, and
:mod:`tests.serve.px4_examples_native` runs the same flows on the native ``mavsdk`` 4.x binding through an
adapter. The connection address is the test's port. A program prints what it does; it ends with
``EXAMPLE FINISHED`` when it ran to its end, and any error a call raises ends it with a traceback, as the
original would.

Run: ``python -m tests.serve.px4_examples NAME udpin://0.0.0.0:PORT GRPC_PORT``.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import sys
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from typing import Any

#: PX4 SITL's default home (PX4_HOME_LAT / PX4_HOME_LON / PX4_HOME_ALT), where the examples' coordinates are.
PX4_HOME = (47.397742, 8.545594, 488.0)


@dataclass(frozen=True)
class Binding:
    """What the flows take from a MAVSDK binding besides the vehicle's plugins: the offboard setpoint types,
    the offboard error and how it names its result, the orbit's yaw behaviour, and the examples' mission item
    (25 m up, 10 m/s, fly-through, nothing else set) and plan."""

    VelocityNedYaw: Any
    PositionNedYaw: Any
    VelocityBodyYawspeed: Any
    Attitude: Any
    OffboardError: type[Exception]
    OrbitYawBehavior: Any
    error_code: Callable[[Any], Any]
    mission_item: Callable[[float, float], Any]
    mission_plan: Callable[[Sequence[Any]], Any]


def grpc_binding() -> Binding:
    """The gRPC MAVSDK-Python (``mavsdk_grpc``): positional constructors, the result under ``_result``."""
    from mavsdk_grpc import action, mission, offboard

    nan = math.nan
    item = mission.MissionItem
    return Binding(
        offboard.VelocityNedYaw, offboard.PositionNedYaw, offboard.VelocityBodyYawspeed, offboard.Attitude,
        offboard.OffboardError, action.OrbitYawBehavior, lambda error: error._result.result,
        lambda lat, lon: item(lat, lon, 25, 10, True, nan, nan, item.CameraAction.NONE, nan, nan, nan, nan, nan,
                              item.VehicleAction.NONE),
        lambda items: mission.MissionPlan(list(items)))


Program = Callable[[Any, Binding], Awaitable[None]]
PROGRAMS: dict[str, Program] = {}


def program(fn: Program) -> Program:
    PROGRAMS[fn.__name__] = fn
    return fn


async def _connected(drone: Any) -> None:
    print("Waiting for drone to connect...")
    async for state in drone.core.connection_state():
        if state.is_connected:
            print("-- Connected to drone!")
            break


async def _global_position_ok(drone: Any, home_too: bool = True) -> None:
    print("Waiting for drone to have a global position estimate...")
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and (health.is_home_position_ok or not home_too):
            print("-- Global position estimate OK")
            break


async def _start_offboard(drone: Any, b: Binding) -> bool:
    print("-- Starting offboard")
    try:
        await drone.offboard.start()
    except b.OffboardError as error:
        print(f"Starting offboard mode failed with error code: {b.error_code(error)}")
        print("-- Disarming")
        await drone.action.disarm()
        return False
    return True


async def _stop_offboard(drone: Any, b: Binding) -> None:
    print("-- Stopping offboard")
    try:
        await drone.offboard.stop()
    except b.OffboardError as error:
        print(f"Stopping offboard mode failed with error code: {b.error_code(error)}")


# ------------------------------------------------------------------------------------------- offboard


@program
async def offboard_velocity_ned(drone: Any, b: Binding) -> None:
    await _connected(drone)
    await _global_position_ok(drone)
    print("-- Arming")
    await drone.action.arm()
    print("-- Setting initial setpoint")
    await drone.offboard.set_velocity_ned(b.VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
    if not await _start_offboard(drone, b):
        return
    for text, sp, wait_s in (
        ("Go up 2 m/s", (0.0, 0.0, -2.0, 0.0), 4),
        ("Go North 2 m/s, turn to face East", (2.0, 0.0, 0.0, 90.0), 4),
        ("Go South 2 m/s, turn to face West", (-2.0, 0.0, 0.0, 270.0), 4),
        ("Go West 2 m/s, turn to face East", (0.0, -2.0, 0.0, 90.0), 4),
        ("Go East 2 m/s", (0.0, 2.0, 0.0, 90.0), 4),
        ("Turn to face South", (0.0, 0.0, 0.0, 180.0), 2),
        ("Go down 1 m/s, turn to face North", (0.0, 0.0, 1.0, 0.0), 4),
    ):
        print(f"-- {text}")
        await drone.offboard.set_velocity_ned(b.VelocityNedYaw(*sp))
        await asyncio.sleep(wait_s)
    await _stop_offboard(drone, b)


@program
async def offboard_position_ned(drone: Any, b: Binding) -> None:
    # (this example neither waits for the connection nor for the position estimate before arming)
    print("-- Arming")
    await drone.action.arm()
    print("-- Setting initial setpoint")
    await drone.offboard.set_position_ned(b.PositionNedYaw(0.0, 0.0, 0.0, 0.0))
    if not await _start_offboard(drone, b):
        return
    for text, sp, wait_s in (
        ("Go 0m North, 0m East, -5m Down", (0.0, 0.0, -5.0, 0.0), 10),
        ("Go 5m North, 0m East, -5m Down, turn to face East", (5.0, 0.0, -5.0, 90.0), 10),
        ("Go 5m North, 10m East, -5m Down", (5.0, 10.0, -5.0, 90.0), 15),
        ("Go 0m North, 10m East, 0m Down, turn to face South", (0.0, 10.0, 0.0, 180.0), 10),
    ):
        print(f"-- {text}")
        await drone.offboard.set_position_ned(b.PositionNedYaw(*sp))
        await asyncio.sleep(wait_s)
    await _stop_offboard(drone, b)


@program
async def offboard_velocity_body(drone: Any, b: Binding) -> None:
    await _connected(drone)
    await _global_position_ok(drone)
    print("-- Arming")
    await drone.action.arm()
    print("-- Setting initial setpoint")
    await drone.offboard.set_velocity_body(b.VelocityBodyYawspeed(0.0, 0.0, 0.0, 0.0))
    if not await _start_offboard(drone, b):
        return
    for text, sp, wait_s in (
        ("Turn clock-wise and climb", (0.0, 0.0, -1.0, 60.0), 5),
        ("Turn back anti-clockwise", (0.0, 0.0, 0.0, -60.0), 5),
        ("Wait for a bit", (0.0, 0.0, 0.0, 0.0), 2),
        ("Fly a circle", (5.0, 0.0, 0.0, 30.0), 15),
        ("Wait for a bit", (0.0, 0.0, 0.0, 0.0), 5),
        ("Fly a circle sideways", (0.0, -5.0, 0.0, 30.0), 15),
        ("Wait for a bit", (0.0, 0.0, 0.0, 0.0), 8),
    ):
        print(f"-- {text}")
        await drone.offboard.set_velocity_body(b.VelocityBodyYawspeed(*sp))
        await asyncio.sleep(wait_s)
    await _stop_offboard(drone, b)


@program
async def offboard_attitude(drone: Any, b: Binding) -> None:
    await _connected(drone)
    print("-- Arming")
    await drone.action.arm()
    print("-- Setting initial setpoint")
    await drone.offboard.set_attitude(b.Attitude(0.0, 0.0, 0.0, 0.0))
    if not await _start_offboard(drone, b):
        return
    for text, sp in (
        ("Go up at 70% thrust", (0.0, 0.0, 0.0, 0.7)),
        ("Roll 30 at 60% thrust", (30.0, 0.0, 0.0, 0.6)),
        ("Roll -30 at 60% thrust", (-30.0, 0.0, 0.0, 0.6)),
        ("Hover at 60% thrust", (0.0, 0.0, 0.0, 0.6)),
    ):
        print(f"-- {text}")
        await drone.offboard.set_attitude(b.Attitude(*sp))
        await asyncio.sleep(2)
    await _stop_offboard(drone, b)
    await drone.action.land()


@program
async def offboard_position_velocity_ned(drone: Any, b: Binding) -> None:
    await _connected(drone)
    await _global_position_ok(drone)
    print("-- Arming")
    await drone.action.arm()
    print("-- Setting initial setpoint")
    await drone.offboard.set_position_ned(b.PositionNedYaw(0.0, 0.0, 0.0, 0.0))
    if not await _start_offboard(drone, b):
        return

    async def print_z_velocity() -> None:
        async for odom in drone.telemetry.position_velocity_ned():
            print(f"{odom.velocity.north_m_s} {odom.velocity.down_m_s}")

    tasks = {asyncio.create_task(print_z_velocity())}
    print("-- Go 0m North, 0m East, -10m Down")
    await drone.offboard.set_position_velocity_ned(b.PositionNedYaw(0.0, 0.0, -10.0, 0.0),
                                                   b.VelocityNedYaw(0.0, 0.0, -1.0, 0.0))
    await asyncio.sleep(10)
    print("-- Go 50m North, 0m East, -10m Down")
    await drone.offboard.set_position_velocity_ned(b.PositionNedYaw(50.0, 0.0, -10.0, 0.0),
                                                   b.VelocityNedYaw(1.0, 0.0, 0.0, 0.0))
    await asyncio.sleep(20)
    await drone.action.land()
    await _stop_offboard(drone, b)
    for task in tasks:
        task.cancel()


# ------------------------------------------------------------------------------------------- action


@program
async def takeoff_and_land(drone: Any, b: Binding) -> None:
    async def print_status_text() -> None:
        try:
            async for status_text in drone.telemetry.status_text():
                print(f"Status: {status_text.type}: {status_text.text}")
        except asyncio.CancelledError:
            return

    status_text_task = asyncio.ensure_future(print_status_text())
    await _connected(drone)
    await _global_position_ok(drone)
    print("-- Arming")
    await drone.action.arm()
    print("-- Taking off")
    await drone.action.takeoff()
    await asyncio.sleep(10)
    print("-- Landing")
    await drone.action.land()
    status_text_task.cancel()


async def _observe_is_in_air(drone: Any, running: list[asyncio.Future[Any]]) -> None:
    """Returns once the vehicle has been in the air and is back on the ground (as the examples do)."""
    was_in_air = False
    async for is_in_air in drone.telemetry.in_air():
        if is_in_air:
            was_in_air = is_in_air
        if was_in_air and not is_in_air:
            for task in running:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            return


@program
async def telemetry_takeoff_and_land(drone: Any, b: Binding) -> None:
    async def print_altitude() -> None:
        previous = None
        async for position in drone.telemetry.position():
            altitude = round(position.relative_altitude_m)
            if altitude != previous:
                previous = altitude
                print(f"Altitude: {altitude}")

    async def print_flight_mode() -> None:
        previous = None
        async for flight_mode in drone.telemetry.flight_mode():
            if flight_mode != previous:
                previous = flight_mode
                print(f"Flight mode: {flight_mode}")
    await _connected(drone)
    running = [asyncio.ensure_future(print_altitude()), asyncio.ensure_future(print_flight_mode())]
    termination = asyncio.ensure_future(_observe_is_in_air(drone, running))
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and health.is_home_position_ok:
            print("-- Global position state is good enough for flying.")
            break
    print("-- Arming")
    await drone.action.arm()
    print("-- Taking off")
    await drone.action.set_takeoff_altitude(10.0)
    await drone.action.takeoff()
    await asyncio.sleep(10)
    print("-- Landing")
    await drone.action.land()
    await termination


@program
async def goto(drone: Any, b: Binding) -> None:
    await _connected(drone)
    await _global_position_ok(drone, home_too=False)
    print("Fetching amsl altitude at home location....")
    absolute_altitude = math.nan
    async for terrain_info in drone.telemetry.home():
        absolute_altitude = terrain_info.absolute_altitude_m
        break
    print("-- Arming")
    await drone.action.arm()
    print("-- Taking off")
    await drone.action.takeoff()
    await asyncio.sleep(1)
    flying_alt = absolute_altitude + 20.0  # 20 m above home; goto_location takes an AMSL altitude
    await drone.action.goto_location(47.399386, 8.535245, flying_alt, 0)


@program
async def do_orbit(drone: Any, b: Binding) -> None:
    await _connected(drone)
    await _global_position_ok(drone)
    position = await drone.telemetry.position().__aiter__().__anext__()
    orbit_height = position.absolute_altitude_m + 10
    print("-- Arming")
    await drone.action.arm()
    print("--- Taking Off")
    await drone.action.takeoff()
    await asyncio.sleep(10)
    print("Do orbit at 10m height from the ground")
    await drone.action.do_orbit(radius_m=10, velocity_ms=2, yaw_behavior=b.OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER,
                                latitude_deg=47.398036222362471, longitude_deg=8.5450146439425509,
                                absolute_altitude_m=orbit_height)
    await asyncio.sleep(60)
    await drone.action.return_to_launch()
    print("--- Landing")


# ------------------------------------------------------------------------------------------- mission


@program
async def mission(drone: Any, b: Binding) -> None:
    await _connected(drone)

    async def print_mission_progress() -> None:
        async for progress in drone.mission.mission_progress():
            print(f"Mission progress: {progress.current}/{progress.total}")

    running = [asyncio.ensure_future(print_mission_progress())]
    termination = asyncio.ensure_future(_observe_is_in_air(drone, running))

    item = b.mission_item  # 25 m up, 10 m/s, fly-through, nothing else set
    plan = b.mission_plan([item(47.398039859999997, 8.5455725400000002), item(47.398036222362471, 8.5450146439425509),
                           item(47.397825620791885, 8.5450092830163271)])
    await drone.mission.set_return_to_launch_after_mission(True)
    print("-- Uploading mission")
    await drone.mission.upload_mission(plan)
    await _global_position_ok(drone)
    print("-- Arming")
    await drone.action.arm()
    print("-- Starting mission")
    await drone.mission.start_mission()
    await termination


# ------------------------------------------------------------------------------------------- info


@program
async def firmware_version(drone: Any, b: Binding) -> None:
    await _connected(drone)
    info = await drone.info.get_version()
    print(info)


@program
async def all_params(drone: Any, b: Binding) -> None:
    await _connected(drone)
    params = await drone.param.get_all_params()
    for p in params.int_params:
        print(p)
    for p in params.float_params:
        print(p)


async def _main(name: str, url: str, grpc_port: int) -> None:
    from mavsdk_grpc import System

    drone = System(port=grpc_port)
    await drone.connect(system_address=url)
    await PROGRAMS[name](drone, grpc_binding())
    print("EXAMPLE FINISHED", flush=True)


if __name__ == "__main__":
    asyncio.run(_main(sys.argv[1], sys.argv[2], int(sys.argv[3])))
