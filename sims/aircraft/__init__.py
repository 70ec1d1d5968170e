"""JSBSim aircraft models and their envelope presets (data: ``<model>/<model>.xml``, ``<model>_envelope.yaml``).

A package only so that packaging carries the data files; JSBSim finds the models through
``sims.fixedwing.SIMS_ROOT`` (its root layout: ``aircraft/<model>/<model>.xml``).
"""
