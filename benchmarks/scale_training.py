"""Scale, training: DCQN as shipped until the map is solved or the budget is spent, by map size.

One question of ``scale.py``, alone: its stage ``train`` with ``scale.py``'s flags (the measurement and its table
are in :mod:`benchmarks.scale_stages.training`). Run alone::

    python benchmarks/scale_training.py --sizes 101 --budget 60 --runs-file /tmp/train.jsonl --out /tmp/train.md
"""

import sys

from benchmarks.scale_common import run_scale
from benchmarks.scale_stages.training import STAGE

if __name__ == "__main__":
    run_scale(["--stages", STAGE, *sys.argv[1:]])
