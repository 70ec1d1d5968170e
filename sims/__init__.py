"""The simulator: vehicle dynamics, sensors, faults, scenarios and the closed loop around Merlin's core."""

# Importing merlin first runs its __init__, which honours MERLIN_USE_SOURCES before any of the simulator's
# compiled modules (merlin._build.COMPILED_MODULES) can load.
import merlin  # noqa: F401
