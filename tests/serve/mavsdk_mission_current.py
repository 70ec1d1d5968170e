"""MAVSDK's ``mission.set_current_mission_item`` against ``merlin serve`` (gRPC ``mavsdk_grpc``): upload the
mission example's three waypoints, set item 2 current on the ground, read the progress MAVSDK reports. Prints
``FLOW ...`` lines and ``FLOW FINISHED``; an error ends it with a traceback.

Run: ``python -m tests.serve.mavsdk_mission_current udpin://0.0.0.0:PORT GRPC_PORT``.
"""

from __future__ import annotations

import asyncio
import sys


async def _main(url: str, grpc_port: int) -> None:
    from mavsdk_grpc import System
    from mavsdk_grpc.mission import MissionItem, MissionPlan

    drone = System(port=grpc_port)
    await drone.connect(system_address=url)
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    nan = float("nan")

    def item(lat: float, lon: float) -> MissionItem:
        return MissionItem(lat, lon, 25, 10, True, nan, nan, MissionItem.CameraAction.NONE, nan, nan, nan, nan, nan,
                           MissionItem.VehicleAction.NONE)

    await drone.mission.upload_mission(MissionPlan([
        item(47.398039859999997, 8.5455725400000002), item(47.398036222362471, 8.5450146439425509),
        item(47.397825620791885, 8.5450092830163271)]))
    await drone.mission.set_current_mission_item(2)
    async for progress in drone.mission.mission_progress():
        print(f"FLOW progress {progress.current}/{progress.total}", flush=True)
        break
    print("FLOW FINISHED", flush=True)


if __name__ == "__main__":
    asyncio.run(_main(sys.argv[1], int(sys.argv[2])))
