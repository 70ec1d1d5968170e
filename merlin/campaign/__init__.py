"""Randomised fault campaigns: many closed-loop runs, their evidence and a reviewer's report.

``spec`` reads a campaign scenario (a scenario file plus ``vary:``) and derives each run's fully resolved
scenario and seed; ``store`` is the append-only results file; ``execute`` flies one run; ``backends``
schedules runs on a local process pool or on Ray; ``aggregate`` turns results into ``campaign.json``;
``limits`` explains a configuration's limits (shared with ``merlin review``); ``html`` writes the report.
"""
