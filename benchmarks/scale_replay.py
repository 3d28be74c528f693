"""Scale, replay buffer: bytes per transition of the shipped buffers, and what state indices would take instead.

One question of ``scale.py``, alone: its stage ``buffer`` with ``scale.py``'s flags (the measurement and its table
are in :mod:`benchmarks.scale_stages.replay`). Run alone::

    python benchmarks/scale_replay.py --runs-file /tmp/replay.jsonl --out /tmp/replay.md
"""

import sys

from benchmarks.scale_common import run_scale
from benchmarks.scale_stages.replay import STAGE

if __name__ == "__main__":
    run_scale(["--stages", STAGE, *sys.argv[1:]])
