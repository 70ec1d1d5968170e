"""Merlin: a trusted core between every command source and the actuators (``docs/architecture.md``)."""

from merlin._build import use_sources_if_asked as _use_sources_if_asked

# MERLIN_USE_SOURCES=1: the hot modules' .py sources even where compiled ones are installed (merlin._build)
_use_sources_if_asked()
