"""Long routes on a city: what each long-route lever buys, in env steps and seconds to a solved map, against the floor.

Routes on a city are 45 hops long at 1,000 intersections and 132 at 10,000 (seed 0, Dreese Lab). The rows: the
CampusNav-v0 entry on the city (today's agent: gamma 0.95, one-step returns, epsilon-greedy from random starts), that
entry with one lever added, and the shipped ``CampusNavCity`` entry (its levers together). The levers:

- ``gamma``: discount 0.99 (the gap between the values of 131 and 132 hops is ``gamma^131 (1 - gamma)``);
- ``nstep``: n-step returns with Dict observations (DCQN's Dict buffer; SB3 refuses them);
- ``curriculum``: starts near the goal first, farther as the agent succeeds (StreetLearn's near-to-far,
  :class:`~campusnav_env.callbacks.StartCurriculumCallback`; the agent never sees the distances);
- ``her``: hindsight relabelling with the goal-conditioned env on the same city (``CampusNavGoal``, episodes to the
  one goal, transitions relabelled with the places reached);
- ``count``: a count bonus on observation digests (exploration towards unvisited views);
- ``memory``: greedy actions planned over the route memory (DCQN's ``route_memory=dict(explore=False)``,
  SPTM/SoRB-style), the critics' greedy action where the memory has no route; ``memory_explore``: the memory as
  shipped (``route_memory=True``): also exploration toward the nearest untried road of the memory in place of
  epsilon's random action;
- ``lean``: lean replay (memory only: it must not change what is learned).

Solved: success >= 0.99 and SPL >= 0.98 from every (start, heading) (``train_until_solved``; time: training seconds,
evaluations excluded). The floor: env steps of the experience-graph agent (``experience_graph_floor.py``'s runs file).
Each run is one process of one torch thread; runs already in the runs file are skipped::

    python benchmarks/long_routes.py --size 1000 --rows base gamma nstep curriculum her count memory explore \
        memory_explore shipped --seeds 0 --budget 300 --workers 2
    python benchmarks/long_routes.py --size 1000 --rows shipped --seeds 0 1 2 --budget 300 --encoder efficientnet-lite0
    python benchmarks/long_routes.py --quick     # a smoke run: 101 intersections, pixel features, seconds
    python benchmarks/long_routes.py --map-seed 23 --rows base memory_explore --floor-runs-file \
        benchmarks/results/new_map_floor_runs.jsonl --out benchmarks/results/new_map.md   # a city never tuned on
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from benchmarks.report import RESULTS_DIR, machine_line, markdown_table, measured_on, publish, read_runs, run_missing
from benchmarks.scale_common import buffer_arrays, peak_memory
from benchmarks.workers import workers_argument

GOAL = "Dreese Lab"
PIXELS = "pixels"
CURRICULUM = "campusnav_env.callbacks.StartCurriculumCallback"
# The registered city ids and their sizes (other sizes: CampusNavCity-v0 with n_intersections)
CITY_IDS = {1_000: "CampusNavCity-v0", 10_000: "CampusNavCity10k-v0"}
BASE_ENTRY = "CampusNav-v0"  # today's agent, as shipped for the campus


@dataclass(frozen=True)
class Row:
    """
    One row of the ablation: an entry, and what is changed in it.

    :param name: What the row is, in words
    :param entry: ``"base"`` (CampusNav-v0's entry) or ``"shipped"`` (the city's own)
    :param overrides: DCQN keyword arguments replaced
    :param variants: Replay variants added to the entry's replay buffer class (``sb3_dcqn.replay``)
    :param callbacks: Callbacks added, as the zoo's ``callback`` key: ``(class path, keyword arguments)``
    :param her: Train on the goal-conditioned env of the same city with ``HerReplayBuffer``
    """

    name: str
    entry: str = "base"
    overrides: dict[str, Any] = field(default_factory=dict)
    variants: tuple[str, ...] = ()
    callbacks: tuple[tuple[str, dict[str, Any]], ...] = ()
    her: bool = False


ROWS = {
    "base": Row("CampusNav-v0's entry (gamma 0.95, 1-step, random starts)"),
    "gamma": Row("+ gamma 0.99", overrides={"gamma": 0.99}),
    "nstep": Row("+ 8-step returns", overrides={"n_steps": 8}),
    "curriculum": Row("+ start curriculum (near to far)", callbacks=((CURRICULUM, {}),)),
    "her": Row("+ hindsight relabelling (goal env, future k=4)", her=True),
    "count": Row(
        "+ count bonus 0.05 on observation digests",
        overrides={"replay_buffer_kwargs": {"count_bonus": 0.05}},
        variants=("count_bonus",),
    ),
    "memory": Row("+ route memory (plans greedy actions)", overrides={"route_memory": {"explore": False}}),
    "memory_explore": Row("+ route memory and exploration toward the untried", overrides={"route_memory": True}),
    "lean": Row("+ lean replay (memory only)", variants=("lean",)),
    "shipped": Row("CampusNavCity entry as shipped", entry="shipped"),
}


@dataclass(frozen=True)
class Job:
    """One run: a row on one map (size, map seed) with one seed."""

    row: str
    size: int
    seed: int
    budget: float
    max_steps: int
    eval_freq: int
    encoder: str
    quick: bool = False
    map_seed: int = 0
    sample: int | None = None  # evaluate a seeded sample of (start, heading) pairs, every pair once it is at the bar


def city_id(size: int) -> str:
    return CITY_IDS.get(size, "CampusNavCity-v0")


def job_entry(job: Job) -> Any:
    """The row's zoo entry (YAML settings, overrides applied), exploration kept in steps whatever the step cap."""
    from sb3_dcqn.zoo_entry import load_zoo_entry
    from sb3_dcqn.zoo_files import default_hyperparams_path

    row = ROWS[job.row]
    entry = load_zoo_entry(default_hyperparams_path(), BASE_ENTRY if row.entry == "base" else city_id(job.size))
    hyperparams = copy.deepcopy(entry.hyperparams)
    hyperparams.update(row.overrides)
    if row.variants:
        from sb3_dcqn.replay import with_variants

        hyperparams["replay_buffer_class"] = with_variants(hyperparams.get("replay_buffer_class"), *row.variants)
    if row.her:
        from stable_baselines3 import HerReplayBuffer

        hyperparams["replay_buffer_class"] = HerReplayBuffer
        hyperparams["replay_buffer_kwargs"] = {"n_sampled_goal": 4, "goal_selection_strategy": "future"}
    explore_steps = hyperparams.get("exploration_fraction", 0.1) * entry.n_timesteps
    hyperparams["exploration_fraction"] = min(1.0, explore_steps / job.max_steps)
    return replace(entry, n_timesteps=job.max_steps, hyperparams=hyperparams, callbacks=entry.callbacks + row.callbacks)


def make_env(job: Job, env_kwargs: dict[str, Any]) -> Any:
    """The city of the job's size and map seed (its goal-conditioned twin for the HER row)."""
    import gymnasium as gym

    import campusnav_env  # noqa: F401  (registers the ids)
    from campusnav_env.features.view_build import with_view_build
    from campusnav_env.maps.campus import generate_city
    from campusnav_env.rendering.street_view import RenderSettings

    small_views = {"render_settings": RenderSettings(64, 48)} if job.encoder == PIXELS else {}
    kwargs = with_view_build(
        {**env_kwargs, "encoder": job.encoder, "map_seed": job.map_seed}, progress=False, **small_views
    )
    if ROWS[job.row].her:
        from campusnav_env.goal_env import CampusNavGoalEnv

        kwargs.pop("n_intersections", None)
        kwargs.pop("map_seed")
        world = generate_city(job.size, seed=job.map_seed)
        return CampusNavGoalEnv(world=world, goals=[GOAL], **{"max_steps": "auto", **kwargs})
    if job.size in CITY_IDS:
        return gym.make(city_id(job.size), **kwargs)
    return gym.make("CampusNavCity-v0", **{**kwargs, "n_intersections": job.size})


def run_one(job: Job) -> dict[str, Any]:
    """Train one row until solved (or the budget is spent) and record what it took."""
    from campusnav_env.callbacks import RouteEvaluationCallback
    from sb3_dcqn.campusnav.experiments import train_until_solved
    from sb3_dcqn.campusnav.solved import SOLVED_SPL, SOLVED_SUCCESS

    entry = job_entry(job)
    begin = time.perf_counter()
    env = make_env(job, entry.env_kwargs)
    env_seconds = time.perf_counter() - begin
    model = entry.make_model(env, seed=job.seed, device="cpu")
    evaluation = RouteEvaluationCallback(
        eval_freq=job.eval_freq,
        goals=[GOAL],
        success_threshold=SOLVED_SUCCESS,
        spl_threshold=SOLVED_SPL,
        stop_when_solved=True,
        every_goal=True,
        sample=job.sample,
    )
    with peak_memory() as peak:
        result = train_until_solved(
            model, job.max_steps, job.budget, job.eval_freq, evaluation, callbacks=entry.make_callbacks()
        )
    at = result.solved_at or result.evaluations[-1]
    last = result.evaluations[-1]
    buffer = model.replay_buffer
    return {
        "row": job.row,
        "size": job.size,
        "map_seed": job.map_seed,
        "seed": job.seed,
        "encoder": job.encoder,
        "budget": job.budget,
        "max_steps": job.max_steps,
        "quick": job.quick,
        "solved": result.solved_at is not None,
        "steps": at.step,
        "seconds": at.train_seconds,
        "episodes": at.episode,
        "final_steps": last.step,
        "final_seconds": last.train_seconds,
        "final_success": last.success_rate,
        "final_spl": last.spl,
        "ms_per_step": 1e3 * last.train_seconds / max(last.step, 1),
        "env_seconds": env_seconds,
        "max_episode_steps": env.unwrapped.max_steps,
        "peak_rss_mb": peak.peak_mb,
        "replay_bytes_per_transition": sum(buffer_arrays(buffer).values()) / buffer.buffer_size,
        "evaluation_seconds": result.evaluation_seconds,
        "evaluations": len(result.evaluations),
        "sample": job.sample,
        **memory_figures(model),
        "curve": result.curve(),
    }


def memory_figures(model: Any) -> dict[str, Any]:
    """The route memory's size (places, bytes and bytes per place, as pickled in the model's file); none without
    one."""
    import pickle

    memory = getattr(model, "memory", None)
    if memory is None:
        return {}
    size = len(pickle.dumps(memory, protocol=pickle.HIGHEST_PROTOCOL))
    return {
        "memory_states": memory.n_states,
        "memory_bytes": size,
        "memory_bytes_per_state": size / max(memory.n_states, 1),
    }


# ------------------------------------------------------------------------------------------------ report
FLOOR_RUNS = RESULTS_DIR / "experience_graph_floor_runs.jsonl"


def floor_steps(
    size: int, key: str = "env_steps", map_seed: int = 0, runs_file: Path = FLOOR_RUNS, memory: str = "poses"
) -> list[int]:
    """
    Env steps to solved of the experience-graph floor on this map (its runs file; records without a map seed are
    of map seed 0, records without a memory are of poses): from every (start, heading) (``env_steps``), or from the
    states a move leads to (``driven_solved_steps``: the floor's exploration alone, without its wait for each
    start-only state to come up as a random start). ``memory``: the floor with the same knowledge as the row
    (``"places"`` for rows with the route memory, ``"poses"`` for the critics alone)
    """
    runs = read_runs(runs_file)
    solved = [
        r
        for r in runs
        if r.get("size") == size
        and r.get("map_seed", 0) == map_seed
        and not r.get("quick")
        and r.get("memory", "poses") == memory
    ]
    return [int(r[key]) for r in solved if r.get(key) is not None and (r.get("solved") or key != "env_steps")]


def row_uses_memory(row: str) -> bool:
    """Whether a row's DCQN keeps the route memory (its floor is then the floor over places)."""
    return row == "shipped" or bool(ROWS[row].overrides.get("route_memory"))


def median_worst(values: list[float], worst_is_max: bool = True, digits: int = 0) -> str:
    """``median (worst)`` of the runs' values; one run: the value."""
    if not values:
        return "-"
    worst = max(values) if worst_is_max else min(values)
    if len(values) == 1:
        return f"{values[0]:,.{digits}f}"
    return f"{statistics.median(values):,.{digits}f} ({worst:,.{digits}f})"


def ablation_table(runs: list[dict[str, Any]], floor_runs: Path = FLOOR_RUNS) -> list[str]:
    """
    One line per (size, map seed, features, row): solved runs, time and env steps to solved, the ratio to the floor
    of the same size and map seed, final scores.
    """
    header = [
        "intersections",
        "map seed",
        "features",
        "row",
        "step cap",
        "seeds",
        "solved",
        "training s to solved: median (worst)",
        "env steps to solved: median (worst)",
        "DCQN steps / floor (median)",
        "DCQN steps / floor's exploration alone",
        "final success: median (worst)",
        "final SPL: median (worst)",
        "ms per env step",
        "peak RSS (MB)",
        "replay B / transition",
    ]
    groups: dict[tuple[int, int, str, str, int], list[dict[str, Any]]] = {}
    for run in runs:
        key = (run["size"], run.get("map_seed", 0), run["encoder"], run["row"], run["max_steps"])
        groups.setdefault(key, []).append(run)
    order = list(ROWS)
    lines = []
    for (size, map_seed, encoder, row, cap), group in sorted(
        groups.items(), key=lambda item: (*item[0][:3], order.index(item[0][3]), item[0][4])
    ):
        solved = [r for r in group if r["solved"]]
        # A run that spent its budget counts with its budget: the worst case is at least that
        seconds = [r["seconds"] if r["solved"] else r["final_seconds"] for r in group]
        steps = [r["steps"] if r["solved"] else r["final_steps"] for r in group]
        ratios = []
        solved_steps = [r["steps"] for r in solved]
        memory = "places" if row_uses_memory(row) else "poses"
        for key in ("env_steps", "driven_solved_steps"):
            floor = floor_steps(size, key, map_seed, floor_runs, memory)
            ratio = statistics.median(solved_steps) / statistics.median(floor) if floor and solved else None
            ratios.append("-" if ratio is None else f"{ratio:.1f}")
        time_cell = median_worst(seconds) + ("" if len(solved) == len(group) else " (misses: their budget)")
        lines.append(
            [
                f"{size:,}",
                str(map_seed),
                encoder,
                ROWS[row].name,
                f"{cap:,}",
                " ".join(str(r["seed"]) for r in sorted(group, key=lambda r: r["seed"])),
                f"{len(solved)}/{len(group)}",
                time_cell,
                median_worst(steps),
                *ratios,
                median_worst([r["final_success"] for r in group], worst_is_max=False, digits=3),
                median_worst([r["final_spl"] for r in group], worst_is_max=False, digits=3),
                f"{statistics.median(r['ms_per_step'] for r in group):.2f}",
                f"{max(r['peak_rss_mb'] for r in group):,.0f}",
                f"{statistics.median(r['replay_bytes_per_transition'] for r in group):,.0f}",
            ]
        )
    return markdown_table(header, lines)


def write_report(runs: list[dict[str, Any]], out: Path, argv: list[str] | None, floor_runs: Path = FLOOR_RUNS) -> None:
    machine = machine_line("runs one after another, each in one process", torch_threads="1 torch thread per run")
    maps = {(r["size"], r.get("map_seed", 0)) for r in runs}
    floors = sorted(
        m
        for m in maps
        if any(floor_steps(m[0], map_seed=m[1], runs_file=floor_runs, memory=memory) for memory in ("places", "poses"))
    )
    lines = [
        "# Long routes: what each lever buys on a city",
        "",
        (__doc__ or "").split("\n\n")[0].replace("\n", " "),
        "",
        measured_on(out, machine),
        "",
        "Solved: success >= 0.99 and SPL >= 0.98 from every (start, heading), goal Dreese Lab, evaluated every N env "
        "steps inside one `learn()` call; time: training seconds, evaluations excluded; a run that spent its budget "
        "counts with its budget and its last evaluation. Floor: the experience-graph agent's median env steps to "
        "solved from every (start, heading), and from the states a move leads to (its exploration alone: the rest "
        "is waiting for each start-only state to come up as a random start, which DCQN, whose critics generalise "
        f"across headings, need not do; `{floor_runs.name}`, the floor of the same size and map seed, with the same "
        "knowledge: over places for the rows with the route memory, over poses for the others; maps with a "
        f"floor: {', '.join(f'{s:,} (map seed {m})' for s, m in floors) or 'none'}). Ratios over solved runs only.",
        "",
        *ablation_table(runs, floor_runs),
    ]
    publish(out, lines, "long_routes.py", argv)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=1_000, help="intersections of the city")
    parser.add_argument("--rows", nargs="+", default=["base", "shipped"], choices=list(ROWS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--budget", type=float, default=300.0, help="training seconds per run (evaluations excluded)")
    parser.add_argument("--max-steps", type=int, default=None, help="env-step cap per run (default: 2M)")
    parser.add_argument("--eval-freq", type=int, default=None, help="env steps between route evaluations")
    parser.add_argument("--encoder", default=PIXELS, help="features: pixels (64x48 views) or efficientnet-lite0")
    parser.add_argument("--map-seed", type=int, default=0, help="seed of the generated city (CampusNavCity's map_seed)")
    parser.add_argument("--quick", action="store_true", help="smoke run: 101 intersections, a few seconds per row")
    parser.add_argument(
        "--floor-runs-file", type=Path, default=FLOOR_RUNS, help="the experience-graph floor's runs (for the ratios)"
    )
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "long_routes.md")
    parser.add_argument("--runs-file", type=Path, default=None, help="default: next to --out, *_runs.jsonl")
    workers_argument(parser)
    args = parser.parse_args(argv)
    if args.quick:
        args.size, args.budget, args.encoder = 101, min(args.budget, 5.0), PIXELS
    eval_freq = args.eval_freq or (1_000 if args.size <= 200 else 5_000 if args.size <= 2_000 else 20_000)
    max_steps = args.max_steps or (3_000 if args.quick else 2_000_000)
    runs_file = args.runs_file or args.out.with_name(args.out.stem + "_runs.jsonl")
    jobs = [
        Job(row, args.size, seed, args.budget, max_steps, eval_freq, args.encoder, args.quick, args.map_seed)
        for row in args.rows
        for seed in args.seeds
    ]
    runs = run_missing(
        runs_file,
        jobs,
        run_one,
        key=lambda r: (r["row"], r["size"], r.get("map_seed", 0), r["seed"], r["encoder"], r["max_steps"]),
        job_key=lambda job: (job.row, job.size, job.map_seed, job.seed, job.encoder, job.max_steps),
        workers=args.workers,
        describe=lambda run: (
            f"{run['row']} seed {run['seed']}: solved {run['solved']} at {run['steps']:,} steps, "
            f"{run['seconds']:.0f} s (success {run['final_success']:.3f}, SPL {run['final_spl']:.3f})"
        ),
    )
    write_report(runs.records, args.out, argv, args.floor_runs_file)


if __name__ == "__main__":
    main()
