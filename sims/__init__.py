"""The simulator: vehicle dynamics, sensors, faults, scenarios and the closed loop around Merlin's core."""

from merlin._build import use_sources_if_asked as _use_sources_if_asked

# the simulator's hot modules are compiled with the core's (merlin._build.COMPILED_MODULES)
_use_sources_if_asked()
