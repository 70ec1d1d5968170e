"""An out-of-process experimental controller written with MAVSDK-Python's Offboard plugin, and nothing else.

It uses only standard MAVSDK calls, exactly as a PX4 offboard example does, so it runs unchanged against
PX4 SITL or against ``merlin serve``: connect, wait for a position estimate, arm, take off, stream a
setpoint, ``offboard.start()`` (which Merlin takes as an authority REQUEST, icd/ICD.md section 6), fly a
velocity pattern, and watch ``telemetry.subscribe_flight_mode()``: when Merlin revokes, the mode leaves OFFBOARD
(e.g. to RETURN_TO_LAUNCH or HOLD) and the controller reports it and stops commanding.

    python -m experimental_controllers.mavsdk_offboard --url udpin://0.0.0.0:14540 --speed 2 --fly-s 20

``--speed`` large enough (e.g. 12 m/s with the conservative envelope) makes the flight leave the
envelope, so the revocation can be watched. Progress lines go to stdout, prefixed ``mavsdk_offboard:``,
so a test can follow them. Exit code 0 when the flight ran to its end (revoked or not), 1 on a failure to
connect, arm, take off or start offboard.
"""

from __future__ import annotations

import argparse
import asyncio
import sys

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, OffboardError, VelocityNedYaw
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync


def say(text: str) -> None:
    print(f"mavsdk_offboard: {text}", flush=True)


async def first_value(gen: object, timeout_s: float) -> object:
    async def first() -> object:
        async for v in gen:  # type: ignore[attr-defined]
            return v
        return None

    return await asyncio.wait_for(first(), timeout_s)


async def wait_until(gen: object, pred: object, timeout_s: float) -> object:
    async def loop() -> object:
        async for v in gen:  # type: ignore[attr-defined]
            if pred(v):  # type: ignore[operator]
                return v
        return None

    return await asyncio.wait_for(loop(), timeout_s)


async def fly(url: str, speed_mps: float, fly_s: float, altitude_m: float, timeout_s: float) -> int:
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)  # MAVSDK's default
    async with Mavsdk(config) as mavsdk:
        await mavsdk.add_any_connection(url)
        system = await mavsdk.first_autopilot(timeout_s=timeout_s)
        if system is None:
            say("no autopilot found")
            return 1
        say("connected")
        action = ActionAsync(system)
        offboard = OffboardAsync(system)
        telemetry = TelemetryAsync(system)

        await wait_until(telemetry.subscribe_health(), lambda h: h.is_global_position_ok and h.is_home_position_ok, timeout_s)
        say("position ok")
        await action.arm()
        say("armed")
        await action.takeoff()
        say("taking off")
        await wait_until(telemetry.subscribe_position(), lambda p: p.relative_altitude_m > altitude_m, timeout_s)
        say("airborne")

        # As MAVSDK's examples do it: one setpoint (MAVSDK re-sends it at 20 Hz from now on), then start().
        # Merlin holds the request (COMMAND_ACK IN_PROGRESS) until its heartbeat rule is met, then grants it
        # (icd/ICD.md section 6): no wait or retry is needed here, as none is against PX4.
        await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
        try:
            await offboard.start()
        except OffboardError as error:  # denied: the reason is in Merlin's STATUSTEXT
            say(f"offboard start denied ({error})")
            return 1
        mode = await wait_until(telemetry.subscribe_flight_mode(), lambda m: m.name == "OFFBOARD", timeout_s)
        say(f"mode {mode.name}")

        revoked = asyncio.Event()

        async def watch_mode() -> None:
            async for m in telemetry.subscribe_flight_mode():
                if m.name != "OFFBOARD":
                    say(f"mode left OFFBOARD: {m.name}")
                    revoked.set()
                    return

        watcher = asyncio.create_task(watch_mode())
        loop = asyncio.get_running_loop()
        t_end = loop.time() + fly_s
        while loop.time() < t_end and not revoked.is_set():
            await offboard.set_velocity_ned(VelocityNedYaw(speed_mps, 0.0, 0.0, 0.0))
            await asyncio.sleep(0.05)
        if not revoked.is_set():
            await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
            await offboard.stop()
            say("offboard stopped")
        watcher.cancel()
        say("revoked" if revoked.is_set() else "done")
        return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="udpin://0.0.0.0:14540", help="MAVSDK connection URL")
    ap.add_argument("--speed", type=float, default=2.0, help="northward speed to fly in OFFBOARD, m/s")
    ap.add_argument("--fly-s", type=float, default=10.0, help="how long to fly in OFFBOARD, s")
    ap.add_argument("--altitude", type=float, default=7.0,
                    help="height above home to reach after takeoff before starting offboard, m (the vehicle's "
                         "own takeoff altitude applies)")
    ap.add_argument("--timeout", type=float, default=60.0, help="timeout of each step, s")
    a = ap.parse_args(argv)
    try:
        return asyncio.run(fly(a.url, a.speed, a.fly_s, a.altitude, a.timeout))
    except Exception as exc:  # reported, not hidden: the exit code says the flight did not happen
        say(f"failed: {type(exc).__name__}: {exc}")
        return 1


if __name__ == "__main__":
    sys.exit(main())
