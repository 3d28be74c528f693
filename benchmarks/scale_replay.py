"""Scale, replay memory: bytes per transition of the replay buffers, and what storing state indices would take.

The arrays of SB3's ``DictReplayBuffer`` (DCQN as shipped) and of ``DCQNDictReplayBuffer`` (experience revision or
prioritised replay on) for the Dict observation at ``view_dim`` 64 and at full 1280-d features (``nbytes /
buffer_size``); and what (node, heading, goal) indices with a feature table gathered at sample time would take
instead (computed and timed, not implemented). Run by ``scale.py`` (stage ``buffer``); alone::

    python benchmarks/scale_replay.py --runs-file /tmp/replay.jsonl --out /tmp/replay.md
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
from report import markdown_table, table_row
from scale_common import BUFFER_SIZE, EFFNET_DIM, MB, VIEW_DIM, Plan, buffer_arrays, seconds_per_call

STAGE = "buffer"
BATCH = 64
SAMPLED_TRANSITIONS = 5_000
TABLE_NODES = 1_000  # the feature table the index sample gathers from


def index_sample_seconds(table: np.ndarray, fill: int, rng: np.random.Generator) -> float:
    """Seconds to sample a batch from (node, heading, goal) index arrays and a feature table, as tensors."""
    import torch as th

    nodes, goals = rng.integers(0, table.shape[0], (2, fill)).astype(np.int32)
    headings = rng.integers(0, 4, fill).astype(np.int8)
    eye = np.eye(4, dtype=np.float32)

    def gather() -> None:
        picks = np.random.randint(0, fill, BATCH)
        for _ in range(2):  # the observation and the next one
            batch = {"views": table[nodes[picks]], "goal_views": table[goals[picks]], "heading": eye[headings[picks]]}
            {key: th.as_tensor(value) for key, value in batch.items()}

    return seconds_per_call(gather, 300)


def measure_replay_buffer(plan: Plan) -> dict[str, Any]:
    """
    Bytes per transition of both replay buffers at view_dim 64 and 1280, from their arrays, and what an index
    buffer would take instead; SB3's sample time against an index gather.

    :param plan: The run (the stage measures the same at every size)
    :return: the stage's record
    """
    from gymnasium import spaces
    from stable_baselines3.common.buffers import DictReplayBuffer

    from sb3_dcqn.buffers import DCQNDictReplayBuffer

    rows = []
    rng = np.random.default_rng(0)
    for cls, label in (
        (DictReplayBuffer, "DictReplayBuffer (shipped)"),
        (DCQNDictReplayBuffer, "DCQNDictReplayBuffer"),
    ):
        for dim in (VIEW_DIM, EFFNET_DIM):
            view = spaces.Box(-10.0, 10.0, shape=(4 * dim,), dtype=np.float32)
            heading = spaces.Box(0.0, 1.0, (4,), np.float32)
            space = spaces.Dict({"views": view, "goal_views": view, "heading": heading})
            # np.zeros reserves the arrays without touching their pages: nothing is allocated here
            buffer = cls(BUFFER_SIZE, space, spaces.Discrete(4), device="cpu", n_envs=1)
            per_transition = {name: nbytes / BUFFER_SIZE for name, nbytes in buffer_arrays(buffer).items()}
            # Instead: node and goal int32 and heading int8, for the observation and the next one, plus the same
            # action/reward/done/timeout (and priority) arrays; features from a (nodes, 4 * dim) table when sampled
            scalars = sum(b for name, b in per_transition.items() if "observations" not in name)
            row = {
                "buffer": label,
                "view_dim": dim,
                "per_transition": per_transition,
                "bytes_per_transition": sum(per_transition.values()),
                "index_bytes_per_transition": 2 * (4 + 1 + 4) + scalars,
                "table_bytes_per_node": 4 * dim * 4,
            }
            if cls is DictReplayBuffer:
                small = cls(SAMPLED_TRANSITIONS, space, spaces.Discrete(4), device="cpu", n_envs=1)
                for key in ("views", "goal_views"):
                    for store in (small.observations, small.next_observations):
                        store[key][:] = rng.standard_normal(store[key].shape, dtype=np.float32)
                small.full = True
                table = rng.standard_normal((TABLE_NODES, 4 * dim), dtype=np.float32)
                row["sample_us"] = 1e6 * seconds_per_call(lambda small=small: small.sample(BATCH), 300)
                row["index_sample_us"] = 1e6 * index_sample_seconds(table, SAMPLED_TRANSITIONS, rng)
            rows.append(row)
    return {"stage": STAGE, "size": 0, "buffer_size": BUFFER_SIZE, "rows": rows}


def bytes_table(record: dict[str, Any]) -> list[str]:
    """Bytes per transition, by array, per buffer and view_dim."""
    rows = record["rows"]
    names = list(dict.fromkeys(name for row in rows for name in row["per_transition"]))
    header = ["array (B per transition)", *(f"{row['buffer']}, view_dim {row['view_dim']}" for row in rows)]
    lines = markdown_table(
        header, [[name, *(f"{row['per_transition'].get(name, 0):,.0f}" for row in rows)] for name in names]
    )
    lines.append(table_row(["**total**", *(f"**{row['bytes_per_transition']:,.0f}**" for row in rows)]))
    return lines


def index_table(record: dict[str, Any], sizes: list[int]) -> list[str]:
    """Features against indices plus a feature table at each map size, and the sample times."""
    n = record["buffer_size"]
    header = [
        "view_dim",
        "features: B/transition",
        f"{n:,} transitions (MB)",
        "indices: B/transition",
        *(f"indices + feature table at {size:,} nodes (MB)" for size in sizes),
        "saving at the largest map",
        f"sample a batch of {BATCH}: features / indices + lookup (us)",
    ]
    rows = []
    for row in (r for r in record["rows"] if "sample_us" in r):
        features = row["bytes_per_transition"] * n
        with_table = [row["index_bytes_per_transition"] * n + row["table_bytes_per_node"] * size for size in sizes]
        rows.append(
            [
                row["view_dim"],
                f"{row['bytes_per_transition']:,.0f}",
                f"{features / MB:,.1f}",
                f"{row['index_bytes_per_transition']:,.0f}",
                *(f"{b / MB:,.1f}" for b in with_table),
                f"{features / with_table[-1]:,.0f}x ({(features - with_table[-1]) / MB:,.0f} MB)",
                f"{row['sample_us']:.0f} / {row['index_sample_us']:.0f}",
            ]
        )
    return markdown_table(header, rows)


def replay_section(record: dict[str, Any], sizes: list[int]) -> list[str]:
    """The results section: what the buffers store, and the two tables."""
    return [
        f"## Replay buffer bytes per transition ({record['buffer_size']:,} transitions, the shipped buffer_size)",
        "",
        "From the buffers' own arrays (`nbytes / buffer_size`). DCQN as shipped uses SB3's `DictReplayBuffer`; "
        "with experience revision or prioritised replay on, `DCQNDictReplayBuffer` (plus, with revision, a "
        "Python index of two 16-byte digests per transition, not counted). SB3 keeps `next_observations` apart "
        "from `observations`, so every feature vector is stored twice per transition, and `goal_views` repeats "
        "the goal's features in every transition. Indices instead (second table): node and goal int32, heading "
        "int8, for the observation and the next one (18 B), the same action/reward/done/timeout arrays, and one "
        "float32 table of 4 x view_dim features per node, gathered at sample time (computed and timed here, not "
        "implemented).",
        "",
        *bytes_table(record),
        "",
        *index_table(record, sizes),
    ]


if __name__ == "__main__":
    from scale import main

    main(["--stages", STAGE, *sys.argv[1:]])
