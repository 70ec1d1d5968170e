"""PX4 ULog output: the file format (:mod:`merlin.ulog.format`), the topics Merlin logs
(:mod:`merlin.ulog.topics`) and a run's flight record written as those topics (:mod:`merlin.ulog.flight`)."""
