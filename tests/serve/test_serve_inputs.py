"""merlin serve builds the core's inputs with the pipeline's builder (merlin.pipeline.InputBuilder), as
merlin sim does: what the links delivered, and the vehicle's redundancy report, reach the core."""

from __future__ import annotations

from typing import Any

from merlin.core.types import Inputs, OperatorInput
from merlin.serve.server import Server
from sims.runner import make_loop
from sims.scenario import Scenario


class _Recording:
    """The server's vehicle side, seen through: :meth:`act` notes the inputs the core is handed, everything
    else goes to the loop. A wrapper: the loop is a compiled class in the compiled build, whose methods
    cannot be replaced on an instance."""

    def __init__(self, loop: Any, seen: list[Inputs]) -> None:
        object.__setattr__(self, "_loop", loop)
        object.__setattr__(self, "_seen", seen)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._loop, name)

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self._loop, name, value)

    def act(self, inputs: Inputs | None) -> Any:
        if inputs is not None:  # None: a tick between the core's, which flies its last decision
            self._seen.append(inputs)
        return self._loop.act(inputs)


def _capture(server: Server) -> list[Inputs]:
    seen: list[Inputs] = []
    server.loop = _Recording(server.loop, seen)  # type: ignore[assignment]
    return seen


def test_what_the_links_delivered_reaches_the_core(server: Server) -> None:
    seen = _capture(server)
    server.hb_t, server.gcs_t, server.rc_t = 0.0, 0.0, 0.0
    server.op = OperatorInput(0.0, False, 0.25)
    server._tick()
    got = seen[-1]
    assert got.experimental.heartbeat_t_s == 0.0 and got.gcs_link_t_s == 0.0
    assert got.operator == OperatorInput(0.0, False, 0.25)
    assert got.redundancy is None  # the default vehicle carries no redundant hardware


def test_a_vehicle_with_redundant_imus_reports_to_the_core_under_serve(server: Server) -> None:
    """The same vehicle side merlin sim flies, with three voted IMUs and one stuck: serve hands the core the
    redundancy report (before the shared builder, the serve path had none)."""
    sc = Scenario.model_validate({"name": "serve", "duration_s": 10.0, "dt_s": server.dt,
                                  "redundancy": {"sensor_voter": True},
                                  "faults": [{"type": "imu_stuck", "start_s": 0.1, "lane": 2}]})
    server.loop = make_loop(sc, server.cfg)
    seen = _capture(server)
    for _ in range(round(1.0 / server.dt)):
        server._tick()
    reports = [i.redundancy for i in seen]
    assert all(r is not None for r in reports)
    assert reports[0].lanes == 3  # type: ignore[union-attr]
    assert reports[-1].lanes == 2 and "imu" in reports[-1].cause  # type: ignore[union-attr]
