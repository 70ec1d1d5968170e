"""Subcommands of the ``merlin`` CLI, one module each, discovered by :mod:`merlin.cli`."""
