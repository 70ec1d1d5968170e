"""The Aerosonde small UAV for JSBSim (data only; see ``aerosonde.xml`` and ``docs/fixed-wing.md``)."""
