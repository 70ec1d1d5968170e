"""Merlin: a trusted core between every command source and the actuators (``docs/architecture.md``)."""

from importlib import metadata as _metadata

from merlin._build import use_sources_if_asked as _use_sources_if_asked

# MERLIN_USE_SOURCES=1: the hot modules' .py sources even where compiled ones are installed (merlin._build)
_use_sources_if_asked()

try:
    #: the installed distribution's version (``pyproject.toml``'s ``project.version``)
    __version__: str = _metadata.version("merlin-autopilot")
except _metadata.PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "0+unknown"
