"""Scale, replay memory: bytes per transition of the replay buffers, the lean buffer's among them, and sampling times.

The arrays of SB3's ``DictReplayBuffer`` (DCQN as shipped), of ``RevisionPrioritizedDictReplayBuffer`` (experience
revision and prioritized replay on) and of ``LeanDictReplayBuffer`` (lean storage: one table of distinct
vectors per Dict key, row indices per transition) for the Dict observation at ``view_dim`` 64 and at full 1280-d
features (``nbytes / buffer_size``; the lean buffer's tables apart, per distinct vector); then the same random walk on
a map of :data:`TABLE_NODES` intersections added to SB3's buffer and to the lean one, and the time to add a transition
and to sample a batch (64 and 256) from each, measured in the same process. Run by ``scale.py`` (stage ``buffer``);
alone::

    python benchmarks/scale_replay.py --runs-file /tmp/replay.jsonl --out /tmp/replay.md
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from benchmarks.report import markdown_table, table_row
from benchmarks.scale_common import (
    BUFFER_SIZE,
    EFFNET_DIM,
    MB,
    VIEW_DIM,
    Plan,
    buffer_arrays,
    seconds_per_call,
)

STAGE = "buffer"
BATCHES = (64, 256)
SAMPLED_TRANSITIONS = 5_000
SAMPLE_REPEATS = 300  # batches sampled per timing
QUICK_TRANSITIONS, QUICK_REPEATS = 500, 30  # the smoke run's (--quick): every table, in a second
TABLE_NODES = 1_000  # the map of the random walk the sampling buffers hold
SHIPPED, READAPTATION, LEAN = (
    "DictReplayBuffer (shipped)",
    "RevisionPrioritizedDictReplayBuffer",
    "LeanDictReplayBuffer",
)


def observation_space(dim: int) -> Any:
    """CampusNav's Dict observation at ``dim`` features per view."""
    from gymnasium import spaces

    view = spaces.Box(-10.0, 10.0, shape=(4 * dim,), dtype=np.float32)
    return spaces.Dict({"views": view, "goal_views": view, "heading": spaces.Box(0.0, 1.0, (4,), np.float32)})


def make_buffer(label: str, size: int, dim: int) -> Any:
    """One of the three buffers, for ``size`` transitions of one env."""
    from gymnasium import spaces
    from stable_baselines3.common.buffers import DictReplayBuffer

    from sb3_dcqn import replay

    classes = {SHIPPED: DictReplayBuffer, READAPTATION: replay.RevisionPrioritizedDictReplayBuffer}
    cls = classes.get(label, replay.LeanDictReplayBuffer)
    # np.zeros reserves the arrays without touching their pages: nothing is allocated here
    return cls(size, observation_space(dim), spaces.Discrete(4), device="cpu", n_envs=1)


def fill_with_a_walk(buffers: list[Any], dim: int, rng: np.random.Generator, transitions: int) -> list[float]:
    """
    Add the same random walk on TABLE_NODES intersections (random views, one goal) to every buffer.

    :param transitions: Length of the walk
    :return: seconds per added transition of each buffer, in order
    """
    views = rng.standard_normal((TABLE_NODES, 4 * dim), dtype=np.float32)
    goal = views[:1].copy()
    eye = np.eye(4, dtype=np.float32)
    nodes = rng.integers(0, TABLE_NODES, transitions + 1)
    headings = rng.integers(0, 4, transitions + 1)
    actions = rng.integers(0, 4, transitions)
    seconds = []
    for buffer in buffers:
        start = time.perf_counter()
        for t in range(transitions):
            obs = {"views": views[nodes[t]][None], "goal_views": goal, "heading": eye[headings[t]][None]}
            nxt = {"views": views[nodes[t + 1]][None], "goal_views": goal, "heading": eye[headings[t + 1]][None]}
            buffer.add(obs, nxt, actions[t : t + 1].reshape(1, 1), np.array([-0.005]), np.array([False]), [{}])
        seconds.append((time.perf_counter() - start) / transitions)
    return seconds


def sample_seconds(buffers: list[Any], batch: int, repeats: int = SAMPLE_REPEATS) -> list[float]:
    """Seconds to sample a batch (as tensors) from each buffer: interleaved twice, the faster of the two."""
    best = [float("inf")] * len(buffers)
    for _ in range(2):
        for i, buffer in enumerate(buffers):
            best[i] = min(best[i], seconds_per_call(lambda buffer=buffer: buffer.sample(batch), repeats))
    return best


def measure_replay_buffer(plan: Plan) -> dict[str, Any]:
    """
    Bytes per transition of the three buffers at view_dim 64 and 1280, from their arrays; the lean buffer's tables;
    add and sample times of SB3's buffer and the lean one holding the same walk.

    :param plan: The run (the stage measures the same at every size)
    :return: the stage's record
    """
    rows, sampling = [], []
    rng = np.random.default_rng(0)
    for label in (SHIPPED, READAPTATION, LEAN):
        for dim in (VIEW_DIM, EFFNET_DIM):
            per_transition = {
                name: nbytes / BUFFER_SIZE
                for name, nbytes in buffer_arrays(make_buffer(label, BUFFER_SIZE, dim)).items()
            }
            rows.append(
                {
                    "buffer": label,
                    "view_dim": dim,
                    "per_transition": per_transition,
                    "bytes_per_transition": sum(per_transition.values()),
                    # Lean: the distinct vectors, one row of 4 x dim float32 per intersection in the views table
                    "table_bytes_per_node": 4 * dim * 4 if label == LEAN else 0,
                }
            )
    transitions, repeats = (QUICK_TRANSITIONS, QUICK_REPEATS) if plan.quick else (SAMPLED_TRANSITIONS, SAMPLE_REPEATS)
    for dim in (VIEW_DIM, EFFNET_DIM):
        shipped, lean = (make_buffer(label, transitions, dim) for label in (SHIPPED, LEAN))
        add_shipped, add_lean = fill_with_a_walk([shipped, lean], dim, rng, transitions)
        tables = {key: table.rows for key, table in lean.observations.items()}
        record = {
            "view_dim": dim,
            "add_us": {SHIPPED: 1e6 * add_shipped, LEAN: 1e6 * add_lean},
            "table_rows": {key: rows_.n_rows for key, rows_ in tables.items()},
            "table_mb": sum(rows_.nbytes for rows_ in tables.values()) / MB,
        }
        for batch in BATCHES:
            t_shipped, t_lean = sample_seconds([shipped, lean], batch, repeats)
            record[f"sample_us_{batch}"] = {SHIPPED: 1e6 * t_shipped, LEAN: 1e6 * t_lean}
        sampling.append(record)
    record = {"stage": STAGE, "size": 0, "buffer_size": BUFFER_SIZE, "rows": rows, "sampling": sampling}
    return record | {"sampled_transitions": transitions}


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
    """SB3's buffer against the lean one plus its views table at each map size."""
    n = record["buffer_size"]
    header = [
        "view_dim",
        "features: B/transition",
        f"{n:,} transitions (MB)",
        "indices: B/transition",
        *(f"lean, with a views table of {size:,} nodes (MB)" for size in sizes),
        "saving at the largest map",
    ]
    by_key = {(row["buffer"], row["view_dim"]): row for row in record["rows"]}
    rows = []
    for dim in sorted({row["view_dim"] for row in record["rows"]}):
        shipped, lean = by_key[(SHIPPED, dim)], by_key[(LEAN, dim)]
        features = shipped["bytes_per_transition"] * n
        with_table = [lean["bytes_per_transition"] * n + lean["table_bytes_per_node"] * size for size in sizes]
        rows.append(
            [
                dim,
                f"{shipped['bytes_per_transition']:,.0f}",
                f"{features / MB:,.1f}",
                f"{lean['bytes_per_transition']:,.0f}",
                *(f"{b / MB:,.1f}" for b in with_table),
                f"{features / with_table[-1]:,.0f}x ({(features - with_table[-1]) / MB:,.0f} MB)",
            ]
        )
    return markdown_table(header, rows)


def sampling_table(record: dict[str, Any]) -> list[str]:
    """Add and sample times of SB3's buffer and the lean one holding the same walk."""
    header = [
        "view_dim",
        "lean tables: distinct rows (views / goal_views / heading), MB",
        "add a transition: SB3 / lean (us)",
        *(f"sample a batch of {batch}: SB3 / lean (us)" for batch in BATCHES),
    ]
    rows = []
    for record_ in record.get("sampling", []):
        counts = record_["table_rows"]
        rows.append(
            [
                record_["view_dim"],
                f"{counts['views']:,} / {counts['goal_views']:,} / {counts['heading']:,}, {record_['table_mb']:,.1f}",
                f"{record_['add_us'][SHIPPED]:.0f} / {record_['add_us'][LEAN]:.0f}",
                *(
                    f"{record_[f'sample_us_{batch}'][SHIPPED]:.0f} / {record_[f'sample_us_{batch}'][LEAN]:.0f}"
                    for batch in BATCHES
                ),
            ]
        )
    return markdown_table(header, rows)


def replay_section(record: dict[str, Any], sizes: list[int]) -> list[str]:
    """The results section: what the buffers store, and the three tables."""
    return [
        f"## Replay buffer bytes per transition ({record['buffer_size']:,} transitions, the shipped buffer_size)",
        "",
        "From the buffers' own arrays (`nbytes / buffer_size`). DCQN as shipped uses SB3's `DictReplayBuffer`; "
        "with experience revision and prioritized replay on, `RevisionPrioritizedDictReplayBuffer` (plus, with "
        "revision, a Python index of two 16-byte digests per transition, not counted). SB3 keeps "
        "`next_observations` apart from `observations`, so every feature vector is stored twice per transition, and "
        "`goal_views` repeats the goal's features in every transition. The lean buffer (`LeanDictReplayBuffer`) "
        "stores each key's distinct "
        "vectors once, in a table shared by observations and next observations, and an int32 row index per key "
        "for the observation and the next one (the rows `observations[...]` below), Discrete actions as uint8; "
        "its tables (second table: one 4 x view_dim float32 row per intersection in the views table, one per goal, "
        "four headings) are gathered at sample time.",
        "",
        *bytes_table(record),
        "",
        *index_table(record, sizes),
        "",
        f"The same random walk of {record.get('sampled_transitions', SAMPLED_TRANSITIONS):,} transitions on "
        f"{TABLE_NODES:,} intersections (random "
        "views, one goal) added to SB3's buffer and to the lean one, then batches sampled from each in the same "
        "process (tensors out; the faster of two interleaved rounds). Adding costs the lean buffer a digest per "
        "vector; sampling gathers from a small table instead of the buffer-sized arrays.",
        "",
        *sampling_table(record),
    ]
