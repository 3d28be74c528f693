"""The ``benchmarks`` package for a script run as a file, ``python benchmarks/NAME.py``.

Python then puts the script's folder, this one, first on ``sys.path`` (not the repository root), so the scripts'
``from benchmarks.report import ...`` finds this module as ``benchmarks``. It makes itself the package by giving
itself the package's folder as its submodule path: ``benchmarks.report`` and the rest load from this folder under
the names ``python -m benchmarks.NAME`` gives them, and no script has to edit ``sys.path``. Run from the repository
root (``python -m benchmarks.NAME``, the tests), ``import benchmarks`` finds the folder itself and this file is one
unused module in it.
"""

from pathlib import Path

__path__ = [str(Path(__file__).resolve().parent)]
