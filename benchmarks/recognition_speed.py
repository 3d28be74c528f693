"""Recognition speed: what "which place is this?" costs the route memory as the number of places grows.

The recogniser (``sb3_dcqn.route_memory.places``) holds one prototype per place. Places here are random pictures of
four views of 64 numbers (the shipped ``view_dim``: whitened features, about 11 apart), visits add fresh noise of
sigma 0.05; the recogniser is calibrated on four visits of each of 200 of them (with two, a window holds too few
repeat pairs for the recogniser to call them a group). Per size: milliseconds per picture for

- **a search**: a picture of a remembered place, no place expected (an episode's start, a move never tried: the
  screen over every place, then the nearest 32 compared view by view);
- **the expected place**: where a remembered move leads (most env steps of training): one comparison;
- **a batch of 1,000**: the route evaluation's pictures, screened in one matrix product;

and the share answered right (known, and the right place) in each. Usage::

    python benchmarks/recognition_speed.py                      # 1,000, 10,000 and 56,000 places
    python benchmarks/recognition_speed.py --sizes 1000 --queries 100
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks.report import RESULTS_DIR, described, machine_line, markdown_table, publish
from sb3_dcqn.route_memory.places import Answer, PlaceRecogniser

VIEWS, WIDTH = 4, 64
NOISE = 0.05
CALIBRATION_PLACES = 200
CALIBRATION_VISITS = 4


def measure(size: int, queries: int, seed: int = 0) -> dict[str, float]:
    """Milliseconds per picture and the share recognised right, for ``size`` remembered places."""
    rng = np.random.default_rng(seed)
    places = rng.normal(0.0, 1.0, (size, VIEWS * WIDTH)).astype(np.float32)

    def visit(index: np.ndarray) -> np.ndarray:
        return (places[index] + rng.normal(0.0, NOISE, (len(index), places.shape[1]))).astype(np.float32)

    recogniser = PlaceRecogniser(VIEWS * WIDTH, VIEWS)
    some = np.arange(min(CALIBRATION_PLACES, size))
    recogniser.show(np.concatenate([visit(some) for _ in range(CALIBRATION_VISITS)]))
    start = time.perf_counter()
    recogniser.recognise(places, add=True)
    add_ms = 1e3 * (time.perf_counter() - start) / size
    asked = rng.integers(size, size=queries)
    record = {"places": size, "add_ms": add_ms}
    for name, expected in (("search", None), ("expected", asked)):
        pictures = visit(asked)
        start = time.perf_counter()
        answers = [
            recogniser.recognise(picture[None], expected=None if expected is None else expected[i : i + 1])
            for i, picture in enumerate(pictures)
        ]
        record[f"{name}_ms"] = 1e3 * (time.perf_counter() - start) / queries
        states = np.array([state[0] for state, _ in answers])
        known = np.array([answer[0] == Answer.KNOWN for _, answer in answers])
        record[f"{name}_right"] = float((known & (states == asked)).mean())
    batch = rng.integers(size, size=1_000)
    pictures = visit(batch)
    start = time.perf_counter()
    states, answers = recogniser.recognise(pictures)
    record["batch_ms"] = 1e3 * (time.perf_counter() - start) / len(batch)
    record["batch_right"] = float(((answers == Answer.KNOWN) & (states == batch)).mean())
    return record


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--sizes", nargs="+", type=int, default=[1_000, 10_000, 56_000])
    parser.add_argument("--queries", type=int, default=300)
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "recognition_speed.md")
    args = parser.parse_args(argv)
    records = [measure(size, args.queries) for size in args.sizes]
    rows = [
        [
            f"{r['places']:,}", f"{r['search_ms']:.2f}", f"{r['search_right']:.3f}", f"{r['expected_ms']:.3f}",
            f"{r['expected_right']:.3f}", f"{r['batch_ms']:.3f}", f"{r['batch_right']:.3f}", f"{r['add_ms']:.2f}",
        ]
        for r in records
    ]  # fmt: skip
    header = [
        "places", "search (ms)", "right", "expected place (ms)", "right", "batch of 1,000 (ms per picture)", "right",
        "adding a place (ms)",
    ]  # fmt: skip
    lines = [
        "# Recognition speed",
        "",
        described(__doc__),
        "",
        machine_line("one process, numpy's BLAS on one thread"),
        "",
        *markdown_table(header, rows),
    ]
    publish(args.out, lines, "recognition_speed.py", argv)


if __name__ == "__main__":
    main()
