"""The same MAVSDK example flows as :mod:`tests.serve.px4_examples`, on the native ``mavsdk`` 4.x binding.

The native binding has its own API (``Mavsdk``, a configuration with a component type, one object per plugin,
``subscribe_*`` streams), so these are the examples' flows (same calls, order and waits) in that API, with
MAVSDK's default component type (a ground station). Flows: mission, takeoff_and_land,
offboard_velocity_ned. Ends with ``EXAMPLE FINISHED``.

Run: ``python -m tests.serve.px4_examples_native NAME udpin://0.0.0.0:PORT``.
"""

from __future__ import annotations

import asyncio
import sys
from collections.abc import Awaitable, Callable
from typing import Any

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan
from mavsdk.asyncio.plugins.offboard import OffboardAsync, OffboardError, VelocityNedYaw
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
