"""Feed optimization of a whole-part program, verified by the twin (``milling-twin optimize``, docs/optimize.md).

``spec.py`` reads ``[optimize]``; ``schedule.py`` gives every program line its feed from the runs so far;
``program_edit.py`` writes the program with those feeds (only F words change); ``run.py`` iterates run, schedule,
rewrite; ``report.py`` writes the report; ``cli.py`` is the command.
"""
