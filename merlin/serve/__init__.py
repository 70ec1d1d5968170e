"""``merlin serve``: the simulated vehicle and the trusted core in real time behind MAVLink links, as PX4
SITL does (icd/ICD.md). :mod:`~merlin.serve.server` is the scheduler and the glue between the links
(:mod:`merlin.link`) and :class:`sims.runner.ClosedLoop`; :mod:`~merlin.serve.streams` plans the telemetry
streams' phases; :mod:`~merlin.serve.records` writes the event log and keeps the timing figures."""

from merlin.serve.records import EventLog, TickStats
from merlin.serve.server import ServeOptions, Server, UdpLinkSpec, install_signal_handlers
from merlin.serve.streams import Stream, plan_streams, replan

__all__ = ["EventLog", "ServeOptions", "Server", "Stream", "TickStats", "UdpLinkSpec", "install_signal_handlers",
           "plan_streams", "replan"]
