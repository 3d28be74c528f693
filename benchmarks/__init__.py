"""The benchmark scripts: each one measures a claim of the project and writes its results file to ``results/``.

Run one from the repository root as ``python -m benchmarks.NAME`` or ``python benchmarks/NAME.py`` (see
``benchmarks/README.md``; a file run finds this package through ``benchmarks/benchmarks.py``, so no script edits
``sys.path``). A script (a module with a ``__main__`` block) imports shared modules only, never another script:
:mod:`benchmarks.report` (the results folder, the machine line, results files and their tables, and
:func:`~benchmarks.report.run_missing`, the loop that runs what the runs file lacks and appends each run),
:mod:`benchmarks.workers` (worker processes), :mod:`benchmarks.campusnav_runs` (tasks, agents, lever sets, goal
conditions), :mod:`benchmarks.closure_runs` (what the closure benchmarks share), :mod:`benchmarks.scale_common` and
:mod:`benchmarks.scale_stages` (``scale.py``'s stages). ``tests/test_benchmark_rules.py`` holds the package to this.
"""
