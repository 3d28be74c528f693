"""How much of the route memory's behaviour its tests pin down: single-behaviour mutations, each run against them.

Each mutation changes one behaviour of ``sb3_dcqn/route_memory/`` (one exact text replacement: a retry removed, an
LRU that evicts the newest, stale routes reused after a road is lost, ``achieved_goal`` read, an aliased state routed
through, a wrong arrival frame, success ignored, ...). The memory's tests (``tests/test_route_memory*.py``) run
against a copy of the tree with that one change; the mutation is *killed* when they fail. A surviving mutation is a
behaviour no test specifies. Writes ``results/memory_mutations.md``.

Usage::

    python benchmarks/memory_mutations.py                 # every mutation (about 30 s each on one core)
    python benchmarks/memory_mutations.py --only 3 17     # some of them
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from benchmarks.report import RESULTS_DIR, machine_line, markdown_table, publish

ROOT = Path(__file__).resolve().parents[1]
MEMORY = "sb3_dcqn/route_memory"
TESTS = sorted(str(path.relative_to(ROOT)) for path in (ROOT / "tests").glob("test_route_memory*.py"))
LAYER_TESTS = "tests/test_route_memory_layer.py"  # trains agents: run apart, not for every mutation


@dataclass(frozen=True)
class Mutation:
    """One behaviour changed: ``old`` (found exactly once in ``module``) becomes ``new``."""

    module: str
    what: str
    old: str
    new: str


MUTATIONS = (
    # The recogniser
    Mutation(
        "places",
        "every view must match (a barrier makes a new place)",
        "self.kth = views - 1 if views >= 4 else views",
        "self.kth = views",
    ),
    Mutation(
        "places",
        "two shared views of four make one place",
        "self.kth = views - 1 if views >= 4 else views",
        "self.kth = max(1, views - 2)",
    ),
    Mutation(
        "places",
        "a second place as near is no reason for doubt",
        "if first <= self.known and (second >= self.new or first <= RATIO * second):",
        "if first <= self.known:",
    ),
    Mutation(
        "places",
        "no unsure band: what is not known is new",
        "if first >= self.new and (not add or self._unlike_every_place(row, pool, per_view)):"
        "  # a query adds none\n            return self._new",
        "if first > self.known:\n            return self._new",
    ),
    Mutation(
        "places",
        "the graph's prior never settles an unsure picture",
        "        if 0 <= expected < self.n_states:\n            # The graph's prior",
        "        if False:\n            # The graph's prior",
    ),
    Mutation(
        "places",
        "no ratio test: a place within known is unsure wherever a second lies within new",
        "(second >= self.new or first <= RATIO * second)",
        "second >= self.new",
    ),
    Mutation(
        "places",
        "a picture with two odd views is a new place",
        "return not (per_view[self.kth - 1] < self.new).any() and not self._matching_but_two_views(per_view).any()",
        "return not (per_view[self.kth - 1] < self.new).any()",
    ),
    Mutation(
        "places",
        "a new picture is judged on the screen's pool alone",
        "if pool is not None and self.n_states <= VERIFY_ALL_STATES:",
        "if False:",
    ),
    Mutation(
        "places",
        "the expected place's odd picture is a new place",
        "if to_expected < PRIOR_REACH * self.new:",
        "if False:",
    ),
    Mutation(
        "places",
        "the expected place is taken over a place clearly nearer",
        "if agrees and first >= RATIO * to_expected:",
        "if agrees:",
    ),
    Mutation(
        "places",
        "two views that agree with the expected place do not settle it",
        "agrees = to_expected < self.new or (self.kth >= 2 and views[self.kth - 2] < self.known)",
        "agrees = to_expected < self.new",
    ),
    Mutation(
        "places",
        "a query never takes the clearly nearest place short of new",
        "if first < self.new and first <= RATIO * second:",
        "if False:",
    ),
    Mutation(
        "places",
        "a query never takes the one place it matches but for two views",
        "if matching.size and (self._owner[matching] == self._owner[matching[0]]).all():",
        "if False:",
    ),
    Mutation(
        "places",
        "a merged place keeps only its own prototype",
        "members = [*self.members(keep).tolist(), *self.members(drop).tolist()]",
        "members = [*self.members(drop).tolist()]",
    ),
    Mutation(
        "places",
        "an expected place is taken anywhere short of new",
        "if distances.min() <= self.known:",
        "if distances.min() < self.new:",
    ),
    Mutation(
        "places",
        "any split of the distances separates places",
        "separates = impostor >= SEPARATION * genuine",
        "separates = impostor > genuine",
    ),
    Mutation(
        "places",
        "views shared bit for bit count in the calibration's distances",
        "identical = per_view <= _IDENTICAL_VIEW * sums",
        "identical = per_view < 0.0",
    ),
    Mutation(
        "places",
        "a later split may put earlier repeat visits among the other places",
        "above = -np.inf if self.genuine is None else float(np.log(self.genuine))",
        "above = -np.inf",
    ),
    Mutation(
        "places",
        "a later split may put the other places among the repeat visits",
        "below = np.inf if self.impostor is None else float(np.log(self.impostor))",
        "below = np.inf",
    ),
    Mutation(
        "places",
        "'new' is judged against random pairs, not each picture's nearest other place",
        "impostor = min(impostor, float(np.percentile(nearest, IMPOSTOR_QUANTILE)))",
        "pass",
    ),
    Mutation(
        "places",
        "a window that does not separate undoes the thresholds",
        "self.separable = separates or bool(self.separable)",
        "self.separable = separates",
    ),
    Mutation(
        "places",
        "a prototype is its first picture (no averaging)",
        "self._prototypes[agreeing, state] += difference[agreeing] / count",
        "pass",
    ),
    Mutation(
        "places",
        "exact repeats do not count in the calibration",
        "zeros = np.zeros(min(self._repeats, len(pairs)), dtype=np.float64)",
        "zeros = np.zeros(0, dtype=np.float64)",
    ),
    Mutation("places", "thresholds never renewed", "return self._shown_since >= self.window", "return False"),
    Mutation("places", "no cap on states", "if not add or self.n_states >= self.max_states:", "if not add:"),
    Mutation(
        "places",
        "guesses before the first calibration",
        "if not self.separable:\n            return -1, Answer.UNSURE",
        "if self.separable is False:\n            return -1, Answer.UNSURE",
    ),
    # The moves
    Mutation(
        "edges",
        "no way back inferred",
        "elif far_outcome in (Outcome.UNTRIED, Outcome.INFERRED, Outcome.INFERRED_BLOCKED):",
        "elif False:",
    ),
    Mutation(
        "edges",
        "two states that several moves lead to by turns are two aliased places",
        "not alike(first, second) and not self._one_place(first, second, source)",
        "not alike(first, second)",
    ),
    Mutation(
        "edges",
        "a merged state's moves are dropped, not handed over",
        "take = theirs & (~ours | (self.last_tried[drop] > self.last_tried[keep]))",
        "take = theirs & ~theirs",
    ),
    Mutation(
        "edges",
        "an alias is never cleared once its states show to be one place",
        "for aliased in [other for other in self.aliased if other != but]:",
        "for aliased in []:",
    ),
    Mutation(
        "edges",
        "a wrong arrival frame on the inferred way back",
        "(slot - self.reverse_action) % self.n_slots)",
        "(slot + 1 - self.reverse_action) % self.n_slots)",
    ),
    Mutation(
        "edges",
        "a bump closes one end only",
        "if self.outcome[far, back] in ROUTES and self.target[far, back] == state:",
        "if False:",
    ),
    Mutation(
        "edges",
        "a bump on an inferred way back closes the road forward",
        "if not observed_road or back is None:",
        "if back is None:",
    ),
    Mutation(
        "edges",
        "an inference revives an observed bump",
        "elif far_outcome in (Outcome.UNTRIED, Outcome.INFERRED, Outcome.INFERRED_BLOCKED):",
        "elif far_outcome in (Outcome.UNTRIED, Outcome.INFERRED, Outcome.INFERRED_BLOCKED, Outcome.BLOCKED):",
    ),
    Mutation(
        "edges",
        "no backoff between retries",
        "wait = self.retry_after * 2 ** np.minimum(failures - 1, MAX_BACKOFF)",
        "wait = self.retry_after",
    ),
    Mutation(
        "edges",
        "retries removed",
        "return closed & (self.clock - self.last_tried[rows] >= wait)",
        "return closed & False",
    ),
    Mutation(
        "edges",
        "a closure is retried at once",
        "return closed & (self.clock - self.last_tried[rows] >= wait)",
        "return closed",
    ),
    Mutation(
        "edges",
        "one odd outcome marks an alias",
        "frequent = sorted((target for target, count in counts.items() if count >= 2), key=lambda t: -counts[t])",
        "frequent = sorted((target for target, count in counts.items() if count >= 1), key=lambda t: -counts[t])",
    ),
    Mutation(
        "edges",
        "two states of one look are an alias anyway",
        "self._drive(state, slot, following, arrival, alike)",
        "self._drive(state, slot, following, arrival, _never_alike)",
    ),
    Mutation(
        "edges",
        "aliased states routed through",
        "if self.aliased:\n            moves &=",
        "if False:\n            moves &=",
    ),
    Mutation(
        "edges",
        "a dead end is a move",
        "self._set(state, slot, Outcome.DEAD_END, following)",
        "self._drive(state, slot, following, arrival)",
    ),
    Mutation(
        "edges",
        "pose states keep the other headings of a lost road",
        "if self.forget_moves_into_on_bump and was_move:",
        "if False:",
    ),
    Mutation(
        "edges",
        "a lost move is not marked",
        "self.lost_move_version = self.version\n\n    def _bump",
        "pass\n\n    def _bump",
    ),
    # The planner and its cache
    Mutation(
        "planner",
        "the LRU evicts the newest",
        "_, (_, evicted) = self._entries.popitem(last=False)",
        "_, (_, evicted) = self._entries.popitem(last=True)",
    ),
    Mutation(
        "planner",
        "an entry larger than the bound is kept",
        "if value.nbytes > self.max_bytes:\n            return",
        "if False:\n            return",
    ),
    Mutation(
        "planner",
        "stale hops reused after a road is lost",
        "if entry is not None and entry[0] >= self.edges.lost_move_version and",
        "if entry is not None and",
    ),
    Mutation(
        "planner",
        "the highest slot wins a tie",
        "best = cost.argmin(axis=1)",
        "best = cost.shape[1] - 1 - cost[:, ::-1].argmin(axis=1)",
    ),
    Mutation(
        "planner",
        "hops count one short",
        "        count = 1\n        hops[level] = count",
        "        count = 0\n        hops[level] = count",
    ),
    # Goals
    Mutation(
        "memory",
        "achieved_goal read where a frame is declared",
        "legacy = place_frame is None and ACHIEVED_GOAL_KEY in keys",
        "legacy = ACHIEVED_GOAL_KEY in keys",
    ),
    Mutation(
        "goals",
        "goal vectors must be equal (no tolerance)",
        "np.abs(vector - row).max() <= self.goal_tolerance:\n                return known",
        "np.abs(vector - row).max() < 0:\n                return known",
    ),
    Mutation(
        "goals",
        "a goal's place is not looked up again when states are added",
        "version = hash((self.version, self.recogniser.version, self._asked_count))",
        "version = hash((self.version, self._asked_count))",
    ),
    Mutation(
        "goals",
        "a goal's place is not looked up again when the matcher has seen more goal pictures",
        "version = hash((self.version, self.recogniser.version, self._asked_count))",
        "version = hash((self.version, self.recogniser.version))",
    ),
    Mutation(
        "goals",
        "the matcher's sample keeps the oldest goal pictures",
        "_keep_newest(self._asked, MAX_GOALS_ASKED)",
        "self._asked = dict(list(self._asked.items())[:MAX_GOALS_ASKED])",
    ),
    Mutation(
        "goals",
        "the matcher is asked again at every new place",
        "if standing and n_states < last[0] * REASK_GROWTH",
        "if standing and n_states <= last[0]",
    ),
    Mutation(
        "goals",
        "the matcher is never asked again as places are added",
        "if standing and n_states < last[0] * REASK_GROWTH",
        "if standing",
    ),
    Mutation(
        "goals",
        "a place ruled out for a goal is offered again",
        "allowed = ~np.isin(labels, list(ruled_out))",
        "allowed = np.ones(labels.size, dtype=bool)",
    ),
    Mutation(
        "goals",
        "the matcher asked for known pictures too",
        "if answers[0] == Answer.KNOWN:\n            return {int(states[0])}",
        "if False:\n            return {int(states[0])}",
    ),
    Mutation(
        "goals",
        "a goal picture the recogniser does not know goes to its nearest place",
        "if self.place_matcher is None or self.recogniser.n_states == 0:\n            return set()",
        "if self.place_matcher is None or self.recogniser.n_states == 0:\n"
        "            return {int(np.argmin(self.recogniser.distances(rows[0])))} "
        "if self.recogniser.n_states else set()",
    ),
    # The facade
    Mutation(
        "memory",
        "no matcher by default for goal pictures",
        "place_matcher = AlignedNearestPlace(views=views) if pictured else None",
        "place_matcher = None",
    ),
    Mutation(
        "memory",
        "a goal is never ruled out where its episode went on",
        "self.goals.rule_out(self.goal_digests(next_observations), went_on)",
        "pass",
    ),
    Mutation(
        "memory",
        "a goal's search is reused after the goal is placed elsewhere",
        'return ("hops", goal, retry, goal_states.tobytes()), is_target',
        'return ("hops", goal, retry), is_target',
    ),
    Mutation(
        "memory",
        "is_success ignored",
        "reached = np.asarray(successes).reshape(-1).astype(bool)",
        "reached = rewards > 0",
    ),
    Mutation(
        "memory",
        "success guessed from the reward",
        "reached = rewards > self.success_reward if self.success_reward is not None else np.zeros_like(terminated)",
        "reached = rewards > 0",
    ),
    Mutation(
        "memory",
        "transitions held before calibration are dropped",
        "for held in pending:\n                self._remember(*held)",
        "for held in pending[-1:]:\n                self._remember(*held)",
    ),
    Mutation("memory", "an unsure picture is recorded as leading outside", "if skip or state < 0:", "if state < 0:"),
    Mutation(
        "memory",
        "states shown to be one place are never merged",
        "        self._merge_twins()\n",
        "",
    ),
    Mutation(
        "memory",
        "no guard on states growing like transitions",
        "elif transitions >= GUARD_WINDOW and new > GROWTH_GUARD * transitions:",
        "elif False:",
    ),
    Mutation(
        "memory",
        "slots ignore the frame",
        "return (frames + actions) % self.n_actions if self._relative() else actions",
        "return actions",
    ),
    Mutation(
        "memory",
        "no retry when passing by an aged closure",
        "slots = np.where((aged := self._retry_due_roads(states)) >= 0, aged, slots)",
        "pass",
    ),
    Mutation(
        "memory",
        "no expected place: no localisation on the graph",
        "expected=self.expected_states(states, slots)",
        "expected=None",
    ),
    Mutation(
        "memory",
        "exploration never returns to a closed slot that is due",
        "return path_to(self.edges, state, lambda here: np.flatnonzero(due[here]).tolist(), exclude)",
        "return None",
    ),
    Mutation(
        "layer",
        "evaluation recognises each picture without the graph's prior",
        "states = self.memory.states_of(batch, expected=self._episode_guard.expected_states(self.memory))",
        "states = self.memory.states_of(batch)",
    ),
    Mutation(
        "places",
        "look-alike siblings decided by the views they share",
        "told = self._told_apart(candidates, unsorted, per_view[self.kth - 1], self.known if add else self.new)",
        "told = None",
    ),
    Mutation(
        "places",
        "the graph's prior takes an expected sibling without a look",
        "if 0 <= expected < self.n_states and expected not in self._siblings:",
        "if 0 <= expected < self.n_states:",
    ),
    Mutation(
        "places",
        "a state split where no view tells its sides apart",
        "        if not differ.any():\n            return -1",
        "        if False:\n            return -1",
    ),
    Mutation(
        "places",
        "a split state keeps its exact pictures",
        "self._exact = {key: owner for key, owner in self._exact.items() if owner != state}",
        "pass",
    ),
    Mutation(
        "places",
        "a picture being remembered takes a query's lenient answer",
        "asked = None if add else self._queried.get(key)",
        "asked = self._queried.get(key)",
    ),
    Mutation(
        "places",
        "a query's answer outlives the places added after it",
        "if asked is not None and asked[1] == self.version:",
        "if asked is not None:",
    ),
    Mutation(
        "memory",
        "aliased states never split",
        "self._split_aliases(disputed)",
        "pass",
    ),
    Mutation(
        "edges",
        "a split's sibling starts with the state's moves",
        "getattr(self, name)[sibling] = fill",
        "getattr(self, name)[sibling] = getattr(self, name)[state]",
    ),
    Mutation(
        "edges",
        "the moved place's way back still leads to the split state",
        "            self.target[moved, back] = sibling",
        "            pass",
    ),
    Mutation(
        "edges",
        "moves into a split state keep their end",
        "        self.forget_moves_into(state, but_from=kept)",
        "        pass",
    ),
    Mutation(
        "edges",
        "a split forgets the kept end's way back too",
        "self.forget_moves_into(state, but_from=kept)",
        "self.forget_moves_into(state)",
    ),
    Mutation(
        "layer",
        "an evaluation episode that went on where the memory placed its goal keeps its route there",
        "            self._episode_guard.envs[env].not_goal |= {int(states[env])}",
        "            pass",
    ),
    Mutation(
        "layer",
        "evaluation gives a move made twice at one place again (only a bump is never repeated)",
        "banned = made >= LOOP_REPEATS",
        "banned = made == np.iinfo(made.dtype).max",
    ),
    Mutation(
        "memory",
        "routes lead to a goal's place where an evaluation's episode went on",
        "goal_states = goal_states[~np.isin(goal_states, list(elsewhere))]",
        "pass",
    ),
    Mutation(
        "goals",
        "a goal picture the matcher names candidates for gets its one answer only (none)",
        "if isinstance(self.place_matcher, CandidateMatcher):",
        "if False:",
    ),
    Mutation(
        "explorer",
        "envs chase the same untried pair",
        "slots = self.memory.path_to_untried(state, self._claimed(env), retry)",
        "slots = self.memory.path_to_untried(state, retry=retry)",
    ),
)


def run_tests(tree: Path, tests: list[str]) -> bool:
    """Whether the tests pass in ``tree`` (one process, one thread)."""
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests],
        cwd=tree, env=env, capture_output=True, text=True, check=False,
    )  # fmt: skip
    return done.returncode == 0


def copy_tree(into: Path) -> None:
    """The packages, tests and settings copied into ``into``."""
    for part in ("sb3_dcqn", "campusnav_env", "tests", "benchmarks", "pyproject.toml"):
        source = ROOT / part
        if source.is_dir():
            shutil.copytree(source, into / part, ignore=shutil.ignore_patterns("__pycache__", "results"))
        else:
            shutil.copy2(source, into / part)


def mutated_copy(mutation: Mutation, into: Path) -> None:
    """The tree copied into ``into`` with the mutation applied (which must match exactly once)."""
    copy_tree(into)
    path = into / MEMORY / f"{mutation.module}.py"
    text = path.read_text()
    count = text.count(mutation.old)
    if count != 1:
        raise ValueError(f"mutation {mutation.what!r}: its text is found {count} times in {path.name}, not once")
    path.write_text(text.replace(mutation.old, mutation.new))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", type=int, nargs="*", help="numbers of the mutations to run (default: all)")
    parser.add_argument(
        "--with-layer",
        action="store_true",
        help=f"also run {LAYER_TESTS} (agents train: slower; always for the layer's)",
    )
    parser.add_argument("--out", type=Path, default=None, help="results file (default: results/memory_mutations.md)")
    args = parser.parse_args()
    tests = TESTS if args.with_layer else [test for test in TESTS if test != LAYER_TESTS]
    chosen = args.only if args.only else list(range(1, len(MUTATIONS) + 1))
    rows, killed = [], 0
    with tempfile.TemporaryDirectory() as scratch:
        baseline = Path(scratch) / "baseline"
        baseline.mkdir()
        copy_tree(baseline)
        if not run_tests(baseline, tests):
            raise SystemExit("the memory's tests fail on the unmutated tree: nothing to measure")
        for number in chosen:
            mutation = MUTATIONS[number - 1]
            tree = Path(scratch) / f"mutant-{number}"
            tree.mkdir()
            mutated_copy(mutation, tree)
            start = time.perf_counter()
            dead = not run_tests(tree, TESTS if mutation.module == "layer" else tests)
            shutil.rmtree(tree)
            killed += dead
            rows.append([str(number), mutation.module, mutation.what, "killed" if dead else "**survived**"])
            print(f"{number:3d} {mutation.module:9s} {'killed  ' if dead else 'SURVIVED'} {mutation.what}"
                  f" ({time.perf_counter() - start:.0f} s)", flush=True)  # fmt: skip
    lines = [
        "# Route memory: single-behaviour mutations against its tests",
        "",
        f"{killed} of {len(rows)} mutations killed by `{' '.join(tests)}`"
        + ("." if args.with_layer else f" (the layer's own mutations also by `{LAYER_TESTS}`)."),
        "",
        machine_line("one pytest process per mutation"),
        "",
        *markdown_table(["#", "module", "behaviour changed", "tests"], rows),
    ]
    publish(args.out or RESULTS_DIR / "memory_mutations.md", lines, "memory_mutations.py", None)


if __name__ == "__main__":
    main()
