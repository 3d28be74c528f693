"""Scale, world build: the map, the 3D world and every street view rendered and encoded into a cold feature cache.

One question of ``scale.py``, alone: its stage ``build`` with ``scale.py``'s flags (the measurement and its table
are in :mod:`benchmarks.scale_stages.world_build`). Run alone::

    python benchmarks/scale_world_build.py --sizes 101 1000 --runs-file /tmp/build.jsonl --out /tmp/build.md
    python benchmarks/scale_world_build.py --sizes 10000 --full-effnet  # the cold 10,000 build in full
    python benchmarks/scale_world_build.py --sizes 1000 --paths workers serial --effnet-sample 500  # old vs new
"""

import argparse
import os
import sys

from benchmarks.scale_common import run_scale
from benchmarks.scale_stages.world_build import PATHS, PATHS_ENV, STAGE


def main(argv: list[str]) -> None:
    """This stage alone, through ``scale.py``'s command line, plus ``--full-effnet`` and ``--paths``."""
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--full-effnet", action="store_true", help="build every size in full with EfficientNet")
    parser.add_argument("--paths", nargs="+", choices=PATHS, default=["workers"], help="EfficientNet builds to run")
    known, rest = parser.parse_known_args(argv)
    os.environ[PATHS_ENV] = ",".join(known.paths)  # the stage processes inherit it
    if known.full_effnet:
        rest += ["--effnet-max-nodes", str(sys.maxsize)]
    run_scale(["--stages", STAGE, *rest])


if __name__ == "__main__":
    main(sys.argv[1:])
