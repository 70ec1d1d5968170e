"""The MAVSDK example flows of :mod:`tests.serve.px4_examples`, run on the native ``mavsdk`` 4.x binding.

The native binding has its own API (``Mavsdk``, a configuration with a component type, one object per plugin,
``subscribe_*`` streams, keyword-only mission items). The flows are not written a second time: an adapter
gives the native plugins the gRPC API's shape (``drone.telemetry.health()`` is the native
``subscribe_health()``) and a :class:`~tests.serve.px4_examples.Binding` supplies the native types, so both
bindings fly the same calls, order and waits. MAVSDK's default component type (a ground station). Ends with
``EXAMPLE FINISHED``.

Run: ``python -m tests.serve.px4_examples_native NAME udpin://0.0.0.0:PORT``.
"""

from __future__ import annotations

import asyncio
import functools
import math
import sys
from collections.abc import AsyncIterator, Sequence
from types import SimpleNamespace
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

from tests.serve.px4_examples import PROGRAMS, Binding


class _Streams:
    """A native plugin in the gRPC API's shape: ``name()`` is the native ``subscribe_name()`` where the
    plugin streams ``name``, the plugin's own ``name`` otherwise."""

    def __init__(self, plugin: Any) -> None:
        self._plugin = plugin

    def __getattr__(self, name: str) -> Any:
        return getattr(self._plugin, f"subscribe_{name}", None) or getattr(self._plugin, name)


async def _connected_once() -> AsyncIterator[Any]:
    # the native binding hands over the system once it is connected (``first_autopilot``)
    yield SimpleNamespace(is_connected=True)


def _mission_item(lat: float, lon: float) -> MissionItem:
    nan = math.nan
    return MissionItem(latitude_deg=lat, longitude_deg=lon, relative_altitude_m=25, speed_m_s=10,
                       is_fly_through=True, gimbal_pitch_deg=nan, gimbal_yaw_deg=nan,
                       camera_action=MissionItem.CameraAction.NONE, loiter_time_s=nan,
                       camera_photo_interval_s=nan, acceptance_radius_m=nan, yaw_deg=nan,
                       camera_photo_distance_m=nan, vehicle_action=MissionItem.VehicleAction.NONE)


def _mission_plan(items: Sequence[MissionItem]) -> MissionPlan:
    return MissionPlan(mission_items=list(items))


NATIVE = Binding(VelocityNedYaw, PositionNedYaw, VelocityBodyYawspeed, Attitude, OffboardError, OrbitYawBehavior,
                 lambda error: error.result.name, _mission_item, _mission_plan)


class NativeDrone:
    """The flows' ``drone`` on a connected native system. A plugin is made when a flow first uses it, so a
    flow creates the plugins it uses and no others (as the native examples do)."""

    def __init__(self, system: Any) -> None:
        self.system = system
        self.core = SimpleNamespace(connection_state=_connected_once)

    @functools.cached_property
    def action(self) -> ActionAsync:
        return ActionAsync(self.system)

    @functools.cached_property
    def offboard(self) -> OffboardAsync:
        return OffboardAsync(self.system)

    @functools.cached_property
    def telemetry(self) -> _Streams:
        return _Streams(TelemetryAsync(self.system))

    @functools.cached_property
    def mission(self) -> _Streams:
        return _Streams(MissionAsync(self.system))

    @functools.cached_property
    def info(self) -> InfoAsync:
        return InfoAsync(self.system)

    @functools.cached_property
    def param(self) -> ParamAsync:
        return ParamAsync(self.system)


async def _main(name: str, url: str) -> None:
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)  # MAVSDK's default
    async with Mavsdk(config) as mavsdk:
        await mavsdk.add_any_connection(url)
        system = await mavsdk.first_autopilot(timeout_s=60.0)
        if system is None:
            raise SystemExit("no autopilot found")
        await PROGRAMS[name](NativeDrone(system), NATIVE)
    print("EXAMPLE FINISHED", flush=True)


if __name__ == "__main__":
    asyncio.run(_main(sys.argv[1], sys.argv[2]))
