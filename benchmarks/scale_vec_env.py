"""Scale, vector envs: env steps/s with ``DummyVecEnv`` and ``SubprocVecEnv``, and one env step by part.

One question of ``scale.py``, alone: its stage ``vecenv`` with ``scale.py``'s flags (the measurement and its table
are in :mod:`benchmarks.scale_stages.vec_env`). Run alone::

    python benchmarks/scale_vec_env.py --runs-file /tmp/vec.jsonl --out /tmp/vec.md
"""

import sys

from benchmarks.scale_common import run_scale
from benchmarks.scale_stages.vec_env import STAGE

if __name__ == "__main__":
    run_scale(["--stages", STAGE, *sys.argv[1:]])
