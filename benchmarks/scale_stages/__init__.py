"""The stages of ``scale.py``, one question each: what a stage measures (a function run in a fresh process) and the
section of ``results/scale.md`` it writes. ``scale.py`` runs them all; ``scale_<stage>.py`` runs one alone."""
