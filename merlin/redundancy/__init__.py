"""Hardware redundancy under the trusted core: sensor-lane voting, duplex IMU FDI, autopilot-lane voting.

* :mod:`~merlin.redundancy.sensor_voter`: triplex voter for IMU, magnetometer, barometer and GPS lanes;
* :mod:`~merlin.redundancy.particle_filter`, :mod:`~merlin.redundancy.duplex_fdi`: seed 003's particle-filter
  FDI for a duplex IMU;
* :mod:`~merlin.redundancy.degradation`: the chain triplex -> duplex (PF FDI) -> simplex;
* :mod:`~merlin.redundancy.lane_voter`: seed 000's autopilot-lane voter, selector and bumpless switch;
* :mod:`~merlin.redundancy.triplex_replay`: replay of seed 000's recorded ULogs;
* :mod:`~merlin.redundancy.events`: the fault reports all of them emit.

See ``docs/redundancy.md``.
"""
