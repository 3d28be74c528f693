"""Scale, feature transform: the env's standardise + PCA of 1280-d views, time and peak memory by map size.

One question of ``scale.py``, alone: its stage ``fit`` with ``scale.py``'s flags (the measurement and its table
are in :mod:`benchmarks.scale_stages.feature_transform`). Run alone::

    python benchmarks/scale_feature_transform.py --sizes 101 1000 10000 --runs-file /tmp/fit.jsonl --out /tmp/fit.md
"""

import sys

from benchmarks.scale_common import run_scale
from benchmarks.scale_stages.feature_transform import STAGE

if __name__ == "__main__":
    run_scale(["--stages", STAGE, *sys.argv[1:]])
