"""Goals found by their pictures: which remembered place a goal photo in a new condition shows, on the campus (or a
generated city: ``--city``).

A route memory (``sb3_dcqn.route_memory``) keeps the ``achieved_goal`` vectors it has seen, each labelled by the
place it was seen at; a goal photo that matches none exactly goes to a place matcher
(``sb3_dcqn.place_recognition``): the nearest reference by cosine similarity with a calibrated threshold, on the raw
vectors (**raw cosine**) or in an embedding learned on the references with a supervised contrastive loss (**learned
embedding**, :func:`~sb3_dcqn.place_recognition.fit_place_matcher`). The vectors are those the agent sees:
``CampusNavGoal-v0`` with the shipped entry's ``env_kwargs`` (``view_dim``; ``hyperparams/dcqn.yml``), goal tables
(``env._goal_tables``) of EfficientNet-Lite0 features (cached on disk after the first build).

References (what the memory holds), per seed (``held_out_split(n_intersections, 0.2, seed)``):

- **driven through**: every intersection pictured in the goal-photo training conditions of
  ``benchmarks/unseen_goals.py`` (``TRAINING_PHOTOS``: noon, 7:00, 16:00, 20:30): episode goals are drawn from the
  80% training goals, and the agent drove through the held-out 20% too, so their ``achieved_goal`` rows are there;
- **noon only**: every intersection at noon (as the agent's own views); with one row per place there is nothing for
  the embedding to learn what stays the same, so only raw cosine is measured;
- **absent places**: the training photo conditions of the 80% only: the held-out intersections' queries must answer
  -1 ("not in memory").

Queries: every intersection under each condition of ``APPEARANCES`` (8:30, 17:30, 19:30 night, passing cars, night
+ cars; none a reference condition). Per condition: accuracy (the matched row's place is the query's), the share
answered "not in memory" and the share matched to a wrong place; for the learned embedding the median and the worst
of seeds 0, 1, 2. Usage::

    python benchmarks/goal_pictures.py            # EfficientNet-Lite0 features (a cold build: about a minute each)
    python benchmarks/goal_pictures.py --quick    # smoke run: pixel features of 64x48 views, seed 0
    python benchmarks/goal_pictures.py --city 200 5 --out benchmarks/results/goal_pictures_city.md  # a world not
                                                  # tuned on: a generated city of 200 intersections, map seed 5
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from benchmarks.campusnav_runs import APPEARANCES, HELD_OUT_FRACTION, TRAINING_PHOTOS, quick_env_kwargs
from benchmarks.report import RESULTS_DIR, machine_line, markdown_table, publish, write_results
from campusnav_env.features.view_build import with_view_build
from campusnav_env.goal_env import CampusNavGoalEnv, held_out_split
from campusnav_env.maps.campus import generate_city
from campusnav_env.maps.road_graph import RoadGraph
from sb3_dcqn.place_recognition import NOT_IN_MEMORY, AlignedNearestPlace, NearestPlace, fit_place_matcher
from sb3_dcqn.zoo_entry import load_zoo_entry
from sb3_dcqn.zoo_files import default_hyperparams_path

ENTRY = "CampusNavGoal-v0"
VIEWS = 4  # a goal vector's views (north, east, south, west)
SEEDS = (0, 1, 2)
MATCHERS = {"raw cosine": False, "learned embedding": True}
REFERENCE_CASES = ("driven through", "noon only")


def goal_tables(quick: bool, world: str | RoadGraph = "campus") -> np.ndarray:
    """
    The goal vectors of every intersection of ``world`` in each condition: ``(conditions, nodes, 4 * D)``, the
    training photo conditions first, then the appearances, in the shipped entry's ``env_kwargs`` (pixel features with
    ``quick``).
    """
    env_kwargs = dict(load_zoo_entry(default_hyperparams_path(), ENTRY).env_kwargs)
    if quick:
        env_kwargs.update(quick_env_kwargs())
    conditions = [*TRAINING_PHOTOS, *APPEARANCES.values()]
    env = CampusNavGoalEnv(world, goal_render_settings=conditions, **with_view_build(env_kwargs, progress=False))
    return env._goal_tables


def scores(rows: np.ndarray, labels: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Accuracy, "not in memory" and wrong-match shares of one condition's queries."""
    answered = rows != NOT_IN_MEMORY
    right = answered & (labels[np.where(answered, rows, 0)] == truth)
    return {
        "accuracy": float(right.mean()),
        "not_in_memory": float((~answered).mean()),
        "wrong": float((answered & ~right).mean()),
    }


def measure(tables: np.ndarray, seed: int) -> dict[str, Any]:
    """Every case and matcher for one seed: per condition, the scores (and the calibrated thresholds)."""
    n_photo, n_nodes = len(TRAINING_PHOTOS), tables.shape[1]
    training, held_out = (np.array(part) for part in held_out_split(n_nodes, HELD_OUT_FRACTION, seed))
    every = np.arange(n_nodes)
    queries = {name: tables[n_photo + k] for k, name in enumerate(APPEARANCES)}

    def references(nodes: np.ndarray, conditions: range) -> tuple[np.ndarray, np.ndarray]:
        return tables[list(conditions)][:, nodes].reshape(-1, tables.shape[2]), np.tile(nodes, len(conditions))

    cases = {
        "driven through": references(every, range(n_photo)),
        "noon only": references(every, range(1)),
        "absent places": references(training, range(n_photo)),
    }
    record: dict[str, Any] = {"seed": seed, "n_nodes": n_nodes, "held_out": held_out.tolist(), "cases": {}}
    for case, (refs, labels) in cases.items():
        for matcher_name, learned in MATCHERS.items():
            if learned and case == "noon only":
                continue  # one row per place: no pair to learn from (PlaceEmbedding.fit refuses)
            start = time.perf_counter()
            matcher = fit_place_matcher(refs, labels, learned=learned, seed=seed)
            fit_seconds = time.perf_counter() - start
            entry: dict[str, Any] = {"threshold": matcher.threshold, "fit_seconds": fit_seconds, "conditions": {}}
            nearest = NearestPlace(embedding=matcher.embedding)  # the same space, no threshold
            for name, photos in queries.items():
                if case == "absent places":
                    absent = matcher.match(photos[held_out], refs, labels)
                    present = matcher.match(photos[training], refs, labels)
                    entry["conditions"][name] = {
                        "absent_rejected": float((absent == NOT_IN_MEMORY).mean()),
                        **scores(present, labels, training),
                    }
                else:
                    entry["conditions"][name] = {
                        **scores(matcher.match(photos, refs, labels), labels, every),
                        "nearest_accuracy": scores(nearest.match(photos, refs, labels), labels, every)["accuracy"],
                    }
            record["cases"][f"{case}/{matcher_name}"] = entry
    record["memory_matcher"] = measure_memory_matcher(tables, training, held_out, seed)
    return record


def asked_in_turn(
    matcher: AlignedNearestPlace, photos: np.ndarray, refs: np.ndarray, labels: np.ndarray, seed: int
) -> np.ndarray:
    """Each photo's candidates (``(m, k)`` rows, the match alone where there is one), matched in a seeded order and
    shown the photos asked before it (as the memory asks its matcher)."""
    answers = np.full((len(photos), matcher.max_candidates), NOT_IN_MEMORY, dtype=np.int64)
    order = np.random.default_rng(seed).permutation(len(photos))
    for position, row in enumerate(order):
        answers[row] = matcher.candidates(photos[[row]], refs, labels, photos[order[:position]])[0]
    return answers


def measure_memory_matcher(
    tables: np.ndarray, training: np.ndarray, held_out: np.ndarray, seed: int
) -> dict[str, dict[str, float]]:
    """The route memory's own matcher (its default) against the agent's own views at noon: every place visited, then
    only the training places (the held-out ones never visited: their photos must get no place)."""
    n_photo, every = len(TRAINING_PHOTOS), np.arange(tables.shape[1])
    conditions = {"noon": tables[0], **{name: tables[n_photo + k] for k, name in enumerate(APPEARANCES)}}
    matcher = AlignedNearestPlace(views=VIEWS)
    results: dict[str, dict[str, float]] = {}
    for name, photos in conditions.items():
        candidates = asked_in_turn(matcher, photos, tables[0], every, seed)
        sure = np.where(candidates[:, 1] < 0, candidates[:, 0], NOT_IN_MEMORY)  # the one answer of `match`
        several = candidates[:, 1] >= 0
        absent = asked_in_turn(matcher, photos[held_out], tables[0][training], training, seed)
        results[name] = {
            **scores(sure, every, every),
            "shortlisted": float(several.mean()),
            "among_candidates": float((candidates == every[:, None]).any(axis=1).mean()),
            "absent_answered": float((absent[:, 0] >= 0).mean()),
        }
    return results


def summary(records: list[dict[str, Any]], key: str, condition: str, metric: str, worst: Callable) -> str:
    """A metric over the seeds: one value when they agree, else ``median (worst)``."""
    return spread_text([r["cases"][key]["conditions"][condition][metric] for r in records if key in r["cases"]], worst)


def spread_text(values: list[float], worst: Callable) -> str:
    """One value when the seeds agree, else ``median (worst)``."""
    median, bad = statistics.median(values), worst(values)
    return f"{median:.3f}" if abs(bad - median) < 5e-4 else f"{median:.3f} ({bad:.3f})"


def report(records: list[dict[str, Any]], quick: bool, d: int, seconds: float, world: str) -> list[str]:
    """The results file's lines (``world``: the campus or a city, as the file names it)."""
    features = "64x48 pixel features (--quick)" if quick else "EfficientNet-Lite0 features"
    n_nodes = records[0]["n_nodes"]
    seeds = ", ".join(str(r["seed"]) for r in records)
    lines = [
        "# Goals found by their pictures",
        "",
        f"`{ENTRY}` goal vectors of {world} (d = {d}: four views, the shipped entry's `view_dim`), {features}, "
        f"{tables_line()}; seeds {seeds} (split `held_out_split({n_nodes}, {HELD_OUT_FRACTION}, seed)` and the learned "
        "embedding's seed). Cells: median over the seeds, the worst in brackets where they differ. Raw cosine "
        "depends on the seed only through the split (absent places).",
        "",
        machine_line("one process"),
        "",
        "## Remembered places, pictured in a new condition",
        "",
        "accuracy: the matched row is of the query's intersection; not in memory: below the calibrated threshold; "
        "wrong: matched to another intersection; nearest: accuracy of the nearest row without a threshold.",
        "",
    ]
    header = ["references", "matcher", "condition", "accuracy", "not in memory", "wrong", "nearest", "threshold"]
    rows = []
    for case in REFERENCE_CASES:
        for matcher_name in MATCHERS:
            key = f"{case}/{matcher_name}"
            if key not in records[0]["cases"]:
                rows.append(
                    [case, matcher_name, "all", "n/a: one row per place, nothing to learn from", "", "", "", ""]
                )
                continue
            thresholds = [r["cases"][key]["threshold"] for r in records]
            for name in APPEARANCES:
                rows.append(
                    [
                        case,
                        matcher_name,
                        name,
                        summary(records, key, name, "accuracy", min),
                        summary(records, key, name, "not_in_memory", max),
                        summary(records, key, name, "wrong", max),
                        summary(records, key, name, "nearest_accuracy", min),
                        f"{statistics.median(thresholds):.3f}",
                    ]
                )
    lines += markdown_table(header, rows)
    lines += [
        "",
        "## Places not in memory",
        "",
        f"References: the training photo conditions of the {100 - round(100 * HELD_OUT_FRACTION)}% training "
        "intersections only. rejected: share of the held-out intersections' queries answered -1 (they must be); "
        "then the scores of the remembered intersections' queries against the same references.",
        "",
    ]
    header = ["matcher", "condition", "absent rejected", "accuracy", "not in memory", "wrong"]
    rows = []
    for matcher_name in MATCHERS:
        key = f"absent places/{matcher_name}"
        for name in APPEARANCES:
            rows.append(
                [
                    matcher_name,
                    name,
                    summary(records, key, name, "absent_rejected", min),
                    summary(records, key, name, "accuracy", min),
                    summary(records, key, name, "not_in_memory", max),
                    summary(records, key, name, "wrong", max),
                ]
            )
    lines += markdown_table(header, rows)
    lines += [
        "",
        "## The route memory's own matcher",
        "",
        "`AlignedNearestPlace(views=4)`, attached by default where an env declares goal pictures: references are the "
        "agent's own views at noon (no other condition, no label), each query matched in a seeded order and shown "
        "the queries asked before it (as the memory asks it). visited: every intersection is a reference; accuracy, "
        "not in memory and wrong: its one answer (`match`); shortlisted: no place clearly the nearest, several "
        "candidates named instead (`candidates`: the memory visits them, nearest first, and rules out each where "
        "the goal's episode goes on; at most 4); found on a tour: the query's intersection is its answer or among its "
        "candidates; absent answered: the share of the held-out intersections' queries given a place or candidates "
        "(wrong ones: they are not among the references, the training 80% only).",
        "",
    ]
    header = [
        "condition",
        "accuracy",
        "not in memory",
        "wrong",
        "shortlisted",
        "found on a tour",
        "absent answered",
    ]
    metrics = (
        ("accuracy", min),
        ("not_in_memory", max),
        ("wrong", max),
        ("shortlisted", max),
        ("among_candidates", min),
        ("absent_answered", max),
    )
    rows = []
    for name in records[0]["memory_matcher"]:
        cells = [spread_text([r["memory_matcher"][name][metric] for r in records], worst) for metric, worst in metrics]
        rows.append([name, *cells])
    lines += markdown_table(header, rows)
    fits = [r["cases"]["driven through/learned embedding"]["fit_seconds"] for r in records]
    lines += [
        "",
        f"Fitting the learned matcher (two embeddings: the cross-fit probe and the final one, "
        f"{len(TRAINING_PHOTOS) * n_nodes} rows): median {statistics.median(fits):.1f} s on one torch thread; "
        f"the whole benchmark {seconds:.0f} s after the features were built or read from the cache.",
    ]
    return lines


def tables_line() -> str:
    """The conditions, as the results file names them."""
    photos = ", ".join("noon" if s is None else f"{s.time_of_day:g} h" for s in TRAINING_PHOTOS)
    return f"reference conditions {photos}; query conditions {', '.join(APPEARANCES)}"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", nargs="+", type=int, help="seeds (default 0 1 2; 0 with --quick)")
    parser.add_argument("--quick", action="store_true", help="smoke run: pixel features of 64x48 views, seed 0")
    parser.add_argument(
        "--city",
        nargs=2,
        type=int,
        metavar=("N", "MAP_SEED"),
        help="a generated city of N intersections (map seed MAP_SEED) instead of the campus",
    )
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "goal_pictures.md")
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    seeds = args.seeds or ([0] if args.quick else list(SEEDS))
    world, world_text = (
        ("campus", "the campus")
        if args.city is None
        else (
            generate_city(args.city[0], seed=args.city[1]),
            f"a generated city of {args.city[0]} intersections (map seed {args.city[1]})",
        )
    )
    tables = goal_tables(args.quick, world)
    start = time.perf_counter()
    records = [measure(tables, seed) for seed in seeds]
    lines = report(records, args.quick, tables.shape[2], time.perf_counter() - start, world_text)
    publish(args.out, lines, "goal_pictures.py", argv)
    write_results(args.out.with_suffix(".json"), json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
