"""The benchmark scripts: each one measures a claim of the project and writes its results file to ``results/``.

Run one from the repository root as ``python -m benchmarks.NAME`` or ``python benchmarks/NAME.py`` (see
``benchmarks/README.md``). Shared pieces: :mod:`benchmarks.report` (the results folder, the machine line, results
files and their tables), :mod:`benchmarks.workers` (worker processes), :mod:`benchmarks.campusnav_runs` (tasks, agents,
lever sets) and :mod:`benchmarks.scale_common` (what ``scale.py``'s stages share).
"""
