"""What the closure benchmarks share (``closures_one_at_a_time.py``, ``closures_eleven.py``, and the closure of
``overestimation.py``): the roads they close, the train -> close -> recover run and its record in the runs file, the
loop over (lever, seed), and the cells, figures and text of their results files.

The roads are chosen from the map alone, never from an agent's routes, so every lever faces the same ones: the
busiest roads of the shortest paths to the goal (one at a time), or the paper's 11 random roads drawn once per seed
(all at once). The run is the glue's (:func:`sb3_dcqn.campusnav.experiments.train_with_closures`).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.campusnav_runs import LEVER_SETS, TASKS, VARIANTS, Task, lever_entry, quick_env_kwargs
from benchmarks.report import RESULTS_DIR, Runs, run_missing
from campusnav_env.closures import ClosureEvent, busiest_road
from campusnav_env.figures import closure_route_panels, training_curves, write_figure
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.recovery import DEFAULT_SPL_THRESHOLD, DEFAULT_SUCCESS_THRESHOLD, Recovery, median_recovery
from sb3_dcqn.campusnav.experiments import ClosurePlan, TrainingOutcome, train_with_closures
from sb3_dcqn.campusnav.levers import LeverSet, lever_callbacks
from sb3_dcqn.campusnav.solved import solved_bar

Road = tuple[int, int]
# A smoke run's levers: DCQN as shipped and the demo's levers
QUICK_LEVERS = ["baseline", "revision_blocked_prioritized"]
# The paper's closure: 11 random roads at once
PAPER_ROADS = 11


def eleven_roads(graph: NavigationGraph, goal: int, seed: int, n_roads: int = PAPER_ROADS) -> list[Road]:
    """
    The roads closed at once for a seed: ``n_roads`` open roads drawn with ``default_rng(seed)`` that keep the goal
    reachable from every node that reaches it now (the draw of ``ClosureEvent(close_random=n_roads, seed=seed)``).
    """
    return graph.sample_closures(n_roads, np.random.default_rng(seed), protect=[goal])


def busiest_closures(graph: NavigationGraph, goal: int, n_closures: int) -> list[Road]:
    """
    Roads to close one after another, chosen from the map alone (so every agent faces the same ones).

    The first is the road used by the most shortest paths from every intersection to the goal; each next one the
    busiest on the shortest paths with the roads before it closed. Roads whose closure would cut the goal off from a
    node that reaches it are skipped (:func:`~campusnav_env.closures.busiest_road`).

    :param graph: The map (not changed)
    :param goal: The goal node
    :param n_closures: Number of roads
    :return: the roads, in the order they close (fewer if no more can be closed)
    """
    trial = graph.copy()
    roads: list[Road] = []
    for _ in range(n_closures):
        routes = [trial.shortest_path(start, goal) for start in range(trial.n_nodes) if start != goal]
        road = busiest_road(trial, routes, [goal])
        if road is None:
            break
        trial.close_road(*road, protect=[goal])
        roads.append(road)
    return roads


def train_then_close(
    task: Task,
    lever_set: LeverSet,
    seed: int,
    closures: Sequence[Sequence[Road]],
    window: int,
    recovery_eval_freq: int,
    env_kwargs: dict[str, Any] | None = None,
) -> TrainingOutcome:
    """
    Train one agent until the map is solved, then keep training while ``closures`` close one event after another
    (the glue's :func:`~sb3_dcqn.campusnav.experiments.train_with_closures`: each window trained out, recovered or not).

    :param task: The map, goal, step cap and time budget of the training to the solved map
    :param lever_set: DCQN's options (and the env's) for this run
    :param seed: Seed of the agent
    :param closures: The roads of each closure event (the first once solved, then one every ``window`` env steps)
    :param window: Env steps of training after each closure
    :param recovery_eval_freq: While recovering, evaluate the routes every this many training episodes
    :param env_kwargs: Env keyword arguments on top of the entry's (e.g. the cheap settings of a smoke run)
    :return: the run
    """
    entry = lever_entry(lever_set, task)
    model = VARIANTS["DCQN"].make_model(task.make_env(entry, **(env_kwargs or {})), entry, seed)
    plan = ClosurePlan(later=[ClosureEvent(at=0, unit="step", close=tuple(roads)) for roads in closures])
    return train_with_closures(
        model,
        plan,
        budget=task.max_steps,
        budget_seconds=task.budget_seconds,
        recovery_budget=window,
        eval_freq=task.eval_freq,
        recovery_eval_freq=recovery_eval_freq,
        stop_when_recovered=False,
        callbacks=lever_callbacks(lever_set.levers),
        progress=False,
    )


def _finite(value: float, digits: int = 3) -> float | None:
    return None if math.isinf(value) else round(float(value), digits)


def recovery_record(number: int, recovery: Recovery, run: TrainingOutcome) -> dict[str, Any]:
    """What the runs file keeps of one closure: the roads, the recovery and the evaluations of its window."""
    closure = recovery.closure
    evaluations = run.evaluation.evaluations
    later = [r.closure for r in run.recoveries if r.closure.step > closure.step]
    window = evaluations[closure.evaluation_index : later[0].evaluation_index if later else len(evaluations)]
    episodes_in_window = (later[0].episode if later else run.evaluation.episodes) - closure.episode
    return {
        "closure": number,
        "roads": [list(road) for road in closure.closed],
        "step": closure.step,
        "episode": closure.episode,
        "routes_affected": closure.routes_affected,
        "success_after": None if recovery.right_after is None else recovery.right_after.success_rate,
        "spl_after": None if recovery.right_after is None else recovery.right_after.spl,
        "recovered": recovery.recovered,
        "episodes": _finite(recovery.episodes, 0),
        "steps": _finite(recovery.steps, 0),
        "seconds": _finite(recovery.seconds),
        "success_end": None if recovery.last is None else recovery.last.success_rate,
        "spl_end": None if recovery.last is None else recovery.last.spl,
        "window_episodes": episodes_in_window,
        # success and SPL against episodes and steps since the closure (the recovery curve)
        "curve": [
            [e.episode - closure.episode, e.step - closure.step, round(e.success_rate, 4), round(e.spl, 4)]
            for e in window
        ],
    }


def run_record(run: TrainingOutcome, **fields: Any) -> dict[str, Any]:
    """What the runs file keeps of one run: ``fields`` (lever, seed, settings), the solve and the recoveries."""
    solved = run.solved_at()
    reached = solved or run.before_closures()
    return {
        **fields,
        "solved": solved is not None,
        "solve_steps": None if reached is None else reached.step,
        "solve_episodes": None if reached is None else reached.episode,
        "solve_seconds": None if reached is None else round(reached.train_seconds, 3),
        "solve_wall_seconds": round(run.first_phase_seconds, 3),
        "closure_wall_seconds": round(run.seconds - run.first_phase_seconds, 3),
        "recoveries": [recovery_record(k, r, run) for k, r in enumerate(run.recoveries, start=1)],
    }


@dataclass(frozen=True)
class _Stored:
    """A recovery read back from the runs file (what :func:`median_recovery` reads)."""

    episodes: float
    steps: float
    seconds: float


def stored_recoveries(records: Sequence[dict[str, Any]]) -> list[_Stored]:
    """The recoveries of the runs file's closure records, never-recovered as ``inf``."""
    return [
        _Stored(*(math.inf if r[key] is None else float(r[key]) for key in ("episodes", "steps", "seconds")))
        for r in records
    ]


def median_episodes(values: Sequence[float]) -> float:
    """The median of recovery episodes (``inf``: never recovered), counted as :func:`median_recovery` counts them."""
    stored: Any = [_Stored(value, 0.0, 0.0) for value in values]  # duck-typed Recovery
    return median_recovery(stored, "episodes")


def medians(records: Sequence[dict[str, Any]]) -> tuple[float, float, float]:
    """Median episodes, env steps and training seconds over closure records (unrecovered count as ``inf``)."""
    stored: Any = stored_recoveries(records)  # duck-typed Recovery: median_recovery reads these three attributes
    return tuple(median_recovery(stored, measure) for measure in ("episodes", "steps", "seconds"))  # type: ignore


def number(value: float | None, digits: int = 0) -> str:
    """A table cell: the value, or "not recovered" for a recovery that never came."""
    if value is None or math.isinf(value):
        return "not recovered"
    if math.isnan(value):
        return "-"
    return f"{value:.{digits}f}"


def roads_text(roads: Sequence[Sequence[int]]) -> str:
    return ", ".join(f"{u}-{v}" for u, v in roads)


def solve_text(run: dict[str, Any]) -> str:
    steps, seconds = run["solve_steps"], run["solve_seconds"]
    where = f"{steps} steps, {seconds:.1f} s" if steps is not None else "-"
    return where if run["solved"] else f"**not solved** (stopped at {where})"


def run_figures(run: TrainingOutcome, prefix: Path, lever: str, title: str) -> list[Path]:
    """
    The route panels and the training curves of one run, next to the results file: ``<prefix>_routes_<lever>.png``
    and ``<prefix>_training_<lever>.png`` (named by lever, so that a run of other levers leaves them alone).
    """
    panels = closure_route_panels(run.closures.graph, run.evaluation.evaluations, run.recoveries, size=520)
    progress = run.progress
    curves = training_curves(
        progress.episode_rewards, progress.episode_lengths, run.recoveries, run.evaluation.evaluations, title=title
    )
    return [
        write_figure(prefix.with_name(f"{prefix.name}_routes_{lever}.png"), panels),
        write_figure(prefix.with_name(f"{prefix.name}_training_{lever}.png"), curves),
    ]


def figure_lever(levers: Sequence[str]) -> str:
    """The lever whose first seed's run gets route panels and training curves: the baseline if it runs."""
    return "baseline" if "baseline" in levers else levers[0]


def shown_levers(levers: Sequence[str], stored: Sequence[dict[str, Any]], seeds: Sequence[int]) -> list[str]:
    """
    The levers of the tables: those asked for, then any other lever whose runs (same settings and seeds) are in the
    runs file, so that an invocation with other levers adds rows instead of replacing the tables.
    """
    known = [r["lever"] for r in stored if r["seed"] in seeds and r["lever"] in LEVER_SETS]
    others = {lever for lever in known if lever not in levers}
    return [*levers, *(lever for lever in LEVER_SETS if lever in others)]


def end_of_window(closure: dict[str, Any]) -> str:
    """A closure record's success / SPL at the end of its window."""
    return "-" if closure["success_end"] is None else f"{closure['success_end']:.3f} / {closure['spl_end']:.3f}"


def closure_benchmark_parser(
    doc: str | None, name: str, window: int, window_help: str, levers: Sequence[str]
) -> argparse.ArgumentParser:
    """The flags the closure benchmarks share: seeds, levers, the window after a closure, evaluation rhythm, files."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument(
        "--levers", nargs="+", choices=sorted(LEVER_SETS), default=list(levers), help="default: " + " ".join(levers)
    )
    parser.add_argument("--window", type=int, default=window, help=window_help)
    parser.add_argument(
        "--eval-every",
        "--recovery-eval-freq",
        dest="eval_every",
        type=positive_int,
        default=2,
        help="training episodes between route evaluations while recovering (1: after every episode); a recovery is "
        "seen at an evaluation, so no recovery shows fewer episodes than this, but 0 (right after the closure)",
    )
    parser.add_argument(
        "--quick", action="store_true", help="smoke run: pixel features, tiny budgets, 2 levers, 1 seed"
    )
    parser.add_argument("--out", type=Path, default=None, help=f"results file (default results/{name}.md)")
    parser.add_argument("--runs-file", type=Path, default=None)
    return parser


def positive_int(text: str) -> int:
    """An argparse type: a whole number of at least 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


# ------------------------------------------------------------------------------------------ the (lever, seed) loop
@dataclass(frozen=True)
class ClosureSetup:
    """
    What a closure benchmark's command line asks for, a smoke run's cuts applied.

    :param out: The results file
    :param runs_file: Its runs file
    :param levers: Lever keys to run
    :param seeds: Seeds to run
    :param task: The map, step cap and budgets of the training to the solved map
    :param env_kwargs: Env arguments on top of the entry's (the smoke run's cheap features)
    :param window: Env steps of training after each closure
    :param eval_every: Training episodes between route evaluations while recovering
    :param quick: A smoke run
    """

    out: Path
    runs_file: Path
    levers: list[str]
    seeds: list[int]
    task: Task
    env_kwargs: dict[str, Any]
    window: int
    eval_every: int
    quick: bool

    @classmethod
    def from_args(cls, args: argparse.Namespace, name: str, default_levers: Sequence[str]) -> ClosureSetup:
        """
        The setup of :func:`closure_benchmark_parser`'s flags (``--quick``: small views, tiny budgets, one seed).

        :param args: The parsed flags
        :param name: The script's stem: the default results file is ``results/<name>.md`` (``<name>_quick.md``)
        :param default_levers: The script's default levers (a smoke run replaces them by :data:`QUICK_LEVERS`)
        """
        out: Path = args.out or RESULTS_DIR / f"{name}{'_quick' if args.quick else ''}.md"
        levers = QUICK_LEVERS if args.quick and args.levers == list(default_levers) else args.levers
        task, env_kwargs, window, seeds = TASKS["campus"], {}, args.window, args.seeds
        if args.quick:
            task = dataclasses.replace(task, max_steps=1_500, budget_seconds=20, eval_freq=500)
            env_kwargs, window, seeds = quick_env_kwargs(), min(window, 300), seeds[:1]
        runs_file = args.runs_file or out.with_name(f"{out.stem}_runs.jsonl")
        return cls(out, runs_file, list(levers), list(seeds), task, env_kwargs, window, args.eval_every, args.quick)

    @property
    def settings(self) -> dict[str, Any]:
        """The fields a stored run must share to be one of this setup's."""
        return {"window": self.window, "recovery_eval_freq": self.eval_every, "quick": self.quick}

    @property
    def prefix(self) -> Path:
        """The results file without its suffix: the figures' names start with it."""
        return self.out.with_name(self.out.stem)

    def probe(self) -> Any:
        """The unwrapped env as the baseline trains on it: its map and goal choose the roads."""
        return self.task.make_env(lever_entry(LEVER_SETS["baseline"], self.task), **self.env_kwargs).unwrapped

    def setup_text(self, what: str) -> str:
        """The results file's ``Setup:`` paragraph: the task, the entry and levers, the training, then ``what``."""
        smoke = " (smoke run: pixel features of 64x48 views, tiny budgets)" if self.quick else ""
        return (
            f"Setup: {self.task.description}{smoke}, DCQN's shipped entry (`hyperparams/dcqn.yml`) plus each lever's "
            f"options. Each (lever, seed) trains from scratch until solved ({solved_bar()} from every (start, "
            f"heading), evaluated every {self.task.eval_freq} steps; cap {self.task.max_steps} steps / "
            f"{self.task.budget_seconds:.0f} s of training), then keeps training (same model) {what}."
        )

    def recovery_text(self) -> str:
        """The results file's ``Recovery:`` definition, with the evaluation period that is its resolution."""
        return (
            f"Recovery: the first route evaluation (right after the closure, then every {self.eval_every} training "
            f"episode{'s' if self.eval_every != 1 else ''}) with success >= {DEFAULT_SUCCESS_THRESHOLD} and SPL >= "
            f"{DEFAULT_SPL_THRESHOLD}; counted in training episodes, env steps and training seconds (evaluations "
            f"excluded) from the closure. A recovery is seen only at an evaluation: none shows fewer than "
            f"{self.eval_every} episodes but 0 (recovered right after the closure); `--eval-every 1` evaluates after "
            "every episode."
        )

    def levers_text(self, levers: Sequence[str]) -> str:
        return "Levers: " + "; ".join(f"{LEVER_SETS[k].name}: `{LEVER_SETS[k].options_text()}`" for k in levers) + "."


@dataclass(frozen=True)
class ClosureJob:
    """
    One run of a closure benchmark.

    :param lever: Lever key
    :param seed: Seed of the agent
    :param closures: The roads of each closure event, in order
    :param figure_title: Title of the run's route panels and training curves; ``None``: the run draws none
    """

    lever: str
    seed: int
    closures: tuple[tuple[Road, ...], ...]
    figure_title: str | None = None


def run_closure_job(setup: ClosureSetup, job: ClosureJob) -> dict[str, Any]:
    """Train, close, recover; the run's record (and its figures beside the results file, if the job draws them)."""
    begin = time.perf_counter()
    run = train_then_close(
        setup.task, LEVER_SETS[job.lever], job.seed, job.closures, setup.window, setup.eval_every, setup.env_kwargs
    )
    record = run_record(
        run, lever=job.lever, seed=job.seed, **setup.settings, wall_seconds=round(time.perf_counter() - begin, 1)
    )
    if job.figure_title is not None:
        run_figures(run, setup.prefix, job.lever, job.figure_title)
    return record


def run_closure_jobs(setup: ClosureSetup, jobs: Sequence[ClosureJob], describe: Callable[[dict], str]) -> Runs:
    """The runs of ``jobs`` not in the runs file yet, one after another in this process, then every stored one."""
    return run_missing(
        setup.runs_file,
        jobs,
        partial(run_closure_job, setup),
        key=lambda record: (record["lever"], record["seed"]),
        job_key=lambda job: (job.lever, job.seed),
        settings=setup.settings,
        describe=describe,
    )


def closure_jobs(
    setup: ClosureSetup, closures: Callable[[int], tuple[tuple[Road, ...], ...]], title: Callable[[str, int], str]
) -> list[ClosureJob]:
    """
    The (lever, seed) jobs of a setup, seed by seed: the first seed's run of :func:`figure_lever` draws its figures.

    :param setup: The setup
    :param closures: The closure events of a seed
    :param title: The figures' title for a (lever, seed)
    """
    drawn = (figure_lever(setup.levers), setup.seeds[0])
    return [
        ClosureJob(lever, seed, closures(seed), title(lever, seed) if (lever, seed) == drawn else None)
        for seed in setup.seeds
        for lever in setup.levers
    ]


def shown_runs(setup: ClosureSetup, runs: Runs) -> tuple[list[str], list[dict[str, Any]]]:
    """The levers of the tables (:func:`shown_levers`) and their runs of the setup's seeds."""
    levers = shown_levers(setup.levers, runs.records, setup.seeds)
    return levers, [r for r in runs.records if r["lever"] in levers and r["seed"] in setup.seeds]


def figures_text(setup: ClosureSetup, what: str) -> str:
    """The results file's ``Figures:`` line: every PNG beside it that belongs to it."""
    pictures = sorted(p.name for p in setup.out.parent.glob(f"{setup.out.stem}_*.png"))
    return f"Figures: {', '.join(f'`{name}`' for name in pictures)} ({what})."


def time_text(runs: Runs, shown: Sequence[dict[str, Any]]) -> str:
    """The results file's ``Time:`` line: the shown runs' wall time, and what this invocation ran."""
    wall = [r["wall_seconds"] for r in shown]
    return (
        f"Time: {len(shown)} runs, {np.sum(wall):.0f} s in all (per run {min(wall, default=0):.0f}-"
        f"{max(wall, default=0):.0f} s, evaluations and the visible closures' rendering included); "
        + runs.invocation_text()
    )


# ------------------------------------------------------------------------------------------------ table cells
def episodes_header(title: str, eval_every: int) -> str:
    """A column of recovery episodes, with the evaluation period that is its floor."""
    return f"{title} (evaluated every {eval_every})"


def median_columns(eval_every: int) -> list[str]:
    """The summary tables' median columns (over a lever's closures)."""
    return [episodes_header("median episodes", eval_every), "median env steps", "median training s"]


def recovery_columns(eval_every: int) -> list[str]:
    """The per-closure tables' recovery columns."""
    return [episodes_header("recovery episodes", eval_every), "env steps", "training s"]


def lever_cells(lever: str, mine: Sequence[dict[str, Any]]) -> tuple[list[Any], float, list[dict[str, Any]]]:
    """
    The first cells of a lever's summary row (the lever, its seeds, their solves, the closures recovered, then
    :func:`median_columns`), its median recovery episodes and its closure records.
    """
    closures = [c for r in mine for c in r["recoveries"]]
    episodes, steps, seconds = medians(closures)
    cells = [
        LEVER_SETS[lever].name,
        len(mine),
        "; ".join(solve_text(r) for r in mine),
        f"{sum(c['recovered'] for c in closures)} / {len(closures)}",
        number(episodes),
        number(steps),
        number(seconds, 1),
    ]
    return cells, episodes, closures


def recovery_cells(closure: dict[str, Any]) -> list[str]:
    """A closure record's :func:`recovery_columns`."""
    return [number(closure["episodes"]), number(closure["steps"]), number(closure["seconds"], 1)]


def window_cell(closure: dict[str, Any]) -> str:
    """A closure record's success / SPL at the end of its window, and the episodes in it."""
    return f"{end_of_window(closure)} ({closure['window_episodes']})"


def runs_by_lever(runs: Sequence[dict[str, Any]], levers: Sequence[str]) -> list[tuple[str, list[dict[str, Any]]]]:
    """Each lever that has runs, with them (in the order of ``runs``)."""
    grouped = [(lever, [r for r in runs if r["lever"] == lever]) for lever in levers]
    return [(lever, mine) for lever, mine in grouped if mine]
