"""Falsification: search the adversary's freedom for the least fence margin (``merlin falsify``;
docs/falsification.md)."""
