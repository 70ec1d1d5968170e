"""``merlin guard``: the trusted core on a companion computer, between an experimental controller and a
real PX4 or ArduPilot autopilot.

Layers, outside in:

- :mod:`~merlin.guard.endpoints`: MAVLink endpoint URLs (UDP, TCP, serial) in pymavlink/MAVSDK style.
- :mod:`merlin.link.autopilot_wire`: the vehicle side's MAVLink (the ardupilotmega dialect, which holds
  common.xml), raw frames split and decoded into typed telemetry (in :mod:`merlin.link`, the only package
  that touches pymavlink).
- :mod:`~merlin.guard.dialects`: the autopilot detected from its HEARTBEAT, and each dialect's mode numbers.
- :mod:`~merlin.guard.failsafe_params`: the start-up check that the autopilot's own failsafe catches a dead
  guard.
- :mod:`~merlin.guard.telemetry`: the autopilot's telemetry as the core's :class:`VehicleState`, stale
  telemetry as a navigation fault.
- :mod:`~merlin.guard.gate`: what the controller may send to the autopilot, and when.
- :mod:`~merlin.guard.trusted`: Merlin's trusted command as the dialect's setpoint or mode.
- :mod:`~merlin.guard.runner`: the loop that ties them to the core.
"""
