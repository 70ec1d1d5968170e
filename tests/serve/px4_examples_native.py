"""The same MAVSDK example flows as :mod:`tests.serve.px4_examples`, on the native ``mavsdk`` 4.x binding.

The native binding has its own API (``Mavsdk``, a configuration with a component type, one object per plugin,
``subscribe_*`` streams), so these are the examples' flows (same calls, order and waits) in that API, with
MAVSDK's default component type (a ground station). Flows: every program of :mod:`tests.serve.px4_examples`
(the twelve MAVSDK examples). Ends with ``EXAMPLE FINISHED``.

Run: ``python -m tests.serve.px4_examples_native NAME udpin://0.0.0.0:PORT``.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import sys
from collections.abc import Awaitable, Callable
from typing import Any

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync, OrbitYawBehavior
from mavsdk.asyncio.plugins.info import InfoAsync
from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan
from mavsdk.asyncio.plugins.offboard import (
    Attitude,
    OffboardAsync,
    OffboardError,
    PositionNedYaw,
    VelocityBodyYawspeed,
    VelocityNedYaw,
)
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

Program = Callable[[Any], Awaitable[None]]
PROGRAMS: dict[str, Program] = {}


def program(fn: Program) -> Program:
    PROGRAMS[fn.__name__] = fn
    return fn


async def _global_position_ok(telemetry: TelemetryAsync) -> None:
    print("Waiting for drone to have a global position estimate...")
    async for health in telemetry.subscribe_health():
        if health.is_global_position_ok and health.is_home_position_ok:
            print("-- Global position estimate OK")
            break


async def _landed_after_flying(telemetry: TelemetryAsync) -> None:
    was_in_air = False
    async for in_air in telemetry.subscribe_in_air():
        was_in_air = was_in_air or in_air
        if was_in_air and not in_air:
            return


@program
async def mission(system: Any) -> None:
    action, mission_, telemetry = ActionAsync(system), MissionAsync(system), TelemetryAsync(system)

    async def print_progress() -> None:
        async for progress in mission_.subscribe_mission_progress():
            print(f"Mission progress: {progress.current}/{progress.total}")

    progress_task = asyncio.ensure_future(print_progress())
    termination = asyncio.ensure_future(_landed_after_flying(telemetry))
    nan = float("nan")

    def item(lat: float, lon: float) -> MissionItem:
        return MissionItem(latitude_deg=lat, longitude_deg=lon, relative_altitude_m=25, speed_m_s=10,
                           is_fly_through=True, gimbal_pitch_deg=nan, gimbal_yaw_deg=nan,
                           camera_action=MissionItem.CameraAction.NONE, loiter_time_s=nan,
                           camera_photo_interval_s=nan, acceptance_radius_m=nan, yaw_deg=nan,
                           camera_photo_distance_m=nan, vehicle_action=MissionItem.VehicleAction.NONE)

    plan = MissionPlan(mission_items=[item(47.398039859999997, 8.5455725400000002),
                                      item(47.398036222362471, 8.5450146439425509),
                                      item(47.397825620791885, 8.5450092830163271)])
    await mission_.set_return_to_launch_after_mission(True)
    print("-- Uploading mission")
    await mission_.upload_mission(plan)
    await _global_position_ok(telemetry)
    print("-- Arming")
    await action.arm()
    print("-- Starting mission")
    await mission_.start_mission()
    await termination
    progress_task.cancel()


@program
async def takeoff_and_land(system: Any) -> None:
    action, telemetry = ActionAsync(system), TelemetryAsync(system)
    await _global_position_ok(telemetry)
    print("-- Arming")
    await action.arm()
    print("-- Taking off")
    await action.takeoff()
    await asyncio.sleep(10)
    print("-- Landing")
    await action.land()


@program
async def offboard_velocity_ned(system: Any) -> None:
    action, offboard, telemetry = ActionAsync(system), OffboardAsync(system), TelemetryAsync(system)
    await _global_position_ok(telemetry)
    print("-- Arming")
    await action.arm()
    print("-- Setting initial setpoint")
    await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
    print("-- Starting offboard")
    try:
        await offboard.start()
    except OffboardError as error:
        print(f"Starting offboard mode failed with error code: {error}")
        await action.disarm()
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
        await offboard.set_velocity_ned(VelocityNedYaw(*sp))
        await asyncio.sleep(wait_s)
    print("-- Stopping offboard")
    try:
        await offboard.stop()
    except OffboardError as error:
        print(f"Stopping offboard mode failed with error code: {error}")


async def _start(action: ActionAsync, offboard: OffboardAsync) -> bool:
    print("-- Starting offboard")
    try:
        await offboard.start()
    except OffboardError as error:
        print(f"Starting offboard mode failed with error code: {error.result.name}")
        print("-- Disarming")
        await action.disarm()
        return False
    return True


async def _stop(offboard: OffboardAsync) -> None:
    print("-- Stopping offboard")
    try:
        await offboard.stop()
    except OffboardError as error:
        print(f"Stopping offboard mode failed with error code: {error.result.name}")


@program
async def offboard_position_ned(system: Any) -> None:
    action, offboard = ActionAsync(system), OffboardAsync(system)
    print("-- Arming")  # (this example neither waits for the position estimate before arming)
    await action.arm()
    print("-- Setting initial setpoint")
    await offboard.set_position_ned(PositionNedYaw(0.0, 0.0, 0.0, 0.0))
    if not await _start(action, offboard):
        return
    for sp, wait_s in (((0.0, 0.0, -5.0, 0.0), 10), ((5.0, 0.0, -5.0, 90.0), 10), ((5.0, 10.0, -5.0, 90.0), 15),
                       ((0.0, 10.0, 0.0, 180.0), 10)):
        print(f"-- Go {sp}")
        await offboard.set_position_ned(PositionNedYaw(*sp))
        await asyncio.sleep(wait_s)
    await _stop(offboard)


@program
async def offboard_velocity_body(system: Any) -> None:
    action, offboard, telemetry = ActionAsync(system), OffboardAsync(system), TelemetryAsync(system)
    await _global_position_ok(telemetry)
    print("-- Arming")
    await action.arm()
    print("-- Setting initial setpoint")
    await offboard.set_velocity_body(VelocityBodyYawspeed(0.0, 0.0, 0.0, 0.0))
    if not await _start(action, offboard):
        return
    for sp, wait_s in (((0.0, 0.0, -1.0, 60.0), 5), ((0.0, 0.0, 0.0, -60.0), 5), ((0.0, 0.0, 0.0, 0.0), 2),
                       ((5.0, 0.0, 0.0, 30.0), 15), ((0.0, 0.0, 0.0, 0.0), 5), ((0.0, -5.0, 0.0, 30.0), 15),
                       ((0.0, 0.0, 0.0, 0.0), 8)):
        print(f"-- Body velocity {sp}")
        await offboard.set_velocity_body(VelocityBodyYawspeed(*sp))
        await asyncio.sleep(wait_s)
    await _stop(offboard)


@program
async def offboard_attitude(system: Any) -> None:
    action, offboard = ActionAsync(system), OffboardAsync(system)
    print("-- Arming")
    await action.arm()
    print("-- Setting initial setpoint")
    await offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.0))
    if not await _start(action, offboard):
        return
    for sp in ((0.0, 0.0, 0.0, 0.7), (30.0, 0.0, 0.0, 0.6), (-30.0, 0.0, 0.0, 0.6), (0.0, 0.0, 0.0, 0.6)):
        print(f"-- Attitude {sp}")
        await offboard.set_attitude(Attitude(*sp))
        await asyncio.sleep(2)
    await _stop(offboard)
    await action.land()


@program
async def offboard_position_velocity_ned(system: Any) -> None:
    action, offboard, telemetry = ActionAsync(system), OffboardAsync(system), TelemetryAsync(system)
    await _global_position_ok(telemetry)
    print("-- Arming")
    await action.arm()
    print("-- Setting initial setpoint")
    await offboard.set_position_ned(PositionNedYaw(0.0, 0.0, 0.0, 0.0))
    if not await _start(action, offboard):
        return

    async def print_z_velocity() -> None:
        async for odom in telemetry.subscribe_position_velocity_ned():
            print(f"{odom.velocity.north_m_s} {odom.velocity.down_m_s}")

    task = asyncio.ensure_future(print_z_velocity())
    print("-- Go 0m North, 0m East, -10m Down")
    await offboard.set_position_velocity_ned(PositionNedYaw(0.0, 0.0, -10.0, 0.0), VelocityNedYaw(0.0, 0.0, -1.0, 0.0))
    await asyncio.sleep(10)
    print("-- Go 50m North, 0m East, -10m Down")
    await offboard.set_position_velocity_ned(PositionNedYaw(50.0, 0.0, -10.0, 0.0), VelocityNedYaw(1.0, 0.0, 0.0, 0.0))
    await asyncio.sleep(20)
    await action.land()
    await _stop(offboard)
    task.cancel()


@program
async def telemetry_takeoff_and_land(system: Any) -> None:
    action, telemetry = ActionAsync(system), TelemetryAsync(system)

    async def print_altitude() -> None:
        previous = None
        async for position in telemetry.subscribe_position():
            altitude = round(position.relative_altitude_m)
            if altitude != previous:
                previous = altitude
                print(f"Altitude: {altitude}")

    async def print_flight_mode() -> None:
        previous = None
        async for flight_mode in telemetry.subscribe_flight_mode():
            if flight_mode != previous:
                previous = flight_mode
                print(f"Flight mode: {flight_mode}")

    running = [asyncio.ensure_future(print_altitude()), asyncio.ensure_future(print_flight_mode())]
    termination = asyncio.ensure_future(_landed_after_flying(telemetry))
    await _global_position_ok(telemetry)
    print("-- Arming")
    await action.arm()
    print("-- Taking off")
    await action.set_takeoff_altitude(10.0)
    await action.takeoff()
    await asyncio.sleep(10)
    print("-- Landing")
    await action.land()
    await termination
    for task in running:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


@program
async def goto(system: Any) -> None:
    action, telemetry = ActionAsync(system), TelemetryAsync(system)
    await _global_position_ok(telemetry)
    print("Fetching amsl altitude at home location....")
    absolute_altitude = math.nan
    async for terrain_info in telemetry.subscribe_home():
        absolute_altitude = terrain_info.absolute_altitude_m
        break
    print("-- Arming")
    await action.arm()
    print("-- Taking off")
    await action.takeoff()
    await asyncio.sleep(1)
    await action.goto_location(47.399386, 8.535245, absolute_altitude + 20.0, 0)


@program
async def do_orbit(system: Any) -> None:
    action, telemetry = ActionAsync(system), TelemetryAsync(system)
    await _global_position_ok(telemetry)
    position = await telemetry.subscribe_position().__anext__()
    orbit_height = position.absolute_altitude_m + 10
    print("-- Arming")
    await action.arm()
    print("--- Taking Off")
    await action.takeoff()
    await asyncio.sleep(10)
    print("Do orbit at 10m height from the ground")
    await action.do_orbit(radius_m=10, velocity_ms=2, yaw_behavior=OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER,
                          latitude_deg=47.398036222362471, longitude_deg=8.5450146439425509,
                          absolute_altitude_m=orbit_height)
    await asyncio.sleep(60)
    await action.return_to_launch()
    print("--- Landing")


@program
async def firmware_version(system: Any) -> None:
    print(await InfoAsync(system).get_version())


@program
async def all_params(system: Any) -> None:
    params = await ParamAsync(system).get_all_params()
    for p in params.int_params:
        print(p)
    for p in params.float_params:
        print(p)


async def _main(name: str, url: str) -> None:
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)  # MAVSDK's default
    async with Mavsdk(config) as mavsdk:
        await mavsdk.add_any_connection(url)
        print("Waiting for drone to connect...")
        system = await mavsdk.first_autopilot(timeout_s=60.0)
        if system is None:
            raise SystemExit("no autopilot found")
        print("-- Connected to drone!")
        await PROGRAMS[name](system)
    print("EXAMPLE FINISHED", flush=True)


if __name__ == "__main__":
    asyncio.run(_main(sys.argv[1], sys.argv[2]))
