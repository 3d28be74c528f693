"""The experience-graph floor: how few env steps an agent that only remembers what it saw needs to solve a map.

The agent (:class:`FloorAgent`) is told nothing but observations, rewards and terminations: no map, no distances, no
action mask. It keeps every transition in an :class:`sb3_dcqn.route_memory.RouteMemory` and acts on it. With the same
knowledge as DCQN's memory (``--memory places``, the default): the env's declared frame (``metadata["place_frame"]``:
views in compass order, actions relative to the heading, two-way roads), so states are places, moves compass slots,
and a driven road's way back is inferred; with ``--memory poses``: exact observations (views and heading) as states
and the actions as edges, the floor before places. Both floors are reported, each beside the learner that has the
same knowledge. It acts:

- **explore** while an untried (state, slot) can be reached over the transitions seen: drive to the nearest one
  (breadth-first search over the known graph) and try it; a collision counts as tried;
- **plan** once nothing untried can be reached from where it stands: drive the shortest route over the transitions
  seen to the goal (breadth-first search back from the transitions that reached it); where it knows none, a fixed
  action.

It runs episodes like a learner (the env's random starts, the env's ``max_steps`` cap) and every ``eval_every`` env
steps its greedy plan-or-explore policy (:meth:`FloorAgent.policy`: the planned action where a route is known, else
the first action towards the nearest untried one, else a fixed action; an unseen observation: the fixed action) is
evaluated from every (start, heading) with ``evaluate_routes``, until solved (``sb3_dcqn.campusnav.solved``: success
>= 0.99 and SPL >= 0.98). Steps to solved are counted at the evaluation that first finds it solved, so they are
exact to within ``eval_every``. It is the floor of sample efficiency for any learner of this env that does not
generalise across observations; :func:`floor_steps` is importable so other benchmarks can report ratios to it.

Features: 64x48 pixel features (the scale benchmarks' cheap build; the floor sees only whether observations are
equal, so the encoder does not change its steps as long as distinct views stay distinct). Runs are appended to a
JSON-lines file (``--runs-file``) as they finish, and a rerun skips those done (same size, seed, eval_every, quick,
step cap); the table is rebuilt from the file. Usage::

    python benchmarks/experience_graph_floor.py --sizes 101 1000 --seeds 0 1 2
    python benchmarks/experience_graph_floor.py --sizes 10000 --seeds 0
    python benchmarks/experience_graph_floor.py --quick            # smoke run: 101 nodes, seed 0
"""

from __future__ import annotations

import argparse
import functools
import statistics
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.report import RESULTS_DIR, machine_line, markdown_table, measured_on, publish, run_missing
from benchmarks.scale_common import GOAL, PIXELS, env_kwargs_for, fmt, make_graph
from campusnav_env.env import CampusNavEnv
from campusnav_env.features.view_build import with_view_build
from campusnav_env.recovery import RouteEvaluation
from campusnav_env.route_evaluation import RouteReport, evaluate_routes
from sb3_dcqn.campusnav.solved import is_solved, solved_bar
from sb3_dcqn.route_memory import RouteMemory, batch_of_one, select_rows

FIXED_ACTION = 0  # forward: what the agent does where it knows nothing
# What the agent knows of the env: its declared frame (places, compass slots, two-way roads), or exact observations
MEMORIES = ("places", "poses")
RUNS_LINE = "runs one after another in one process, evaluations included in the wall time"


def default_eval_every(n_nodes: int) -> int:
    """Env steps between evaluations: an evaluation routes all ~4N (start, heading) pairs, so sparser on big maps."""
    return 250 if n_nodes <= 200 else 2_500 if n_nodes <= 2_000 else 25_000


@dataclass(frozen=True)
class FloorResult:
    """
    One run of the experience-graph floor.

    :param solved: Whether an evaluation found the map solved within the step cap
    :param env_steps: Env steps at that evaluation (or at the cap)
    :param episodes: Episodes started by then
    :param wall_seconds: Wall time, evaluations included
    :param evaluation_seconds: Of which evaluations
    :param evaluations: Evaluations run
    :param success: Success rate of the last evaluation
    :param spl: SPL of the last evaluation
    :param states: States remembered (places, or (observation) poses)
    :param tried: (state, slot) pairs tried
    :param driven_solved_steps: Env steps at the first evaluation at the solved bar on the routes from the states a
        move leads to (the start-only states left out: the coverage of random starts aside), ``None`` if never
    :param driven_solved_episodes: Episodes started by then
    """

    solved: bool
    env_steps: int
    episodes: int
    wall_seconds: float
    evaluation_seconds: float
    evaluations: int
    success: float
    spl: float
    states: int
    tried: int
    driven_solved_steps: int | None = None
    driven_solved_episodes: int | None = None


class FloorAgent:
    """
    The experience-graph agent (see the module docstring): explores towards untried actions, then plans.

    :param graph: Its memory of transitions (empty to start with)
    :param fixed_action: The action where it knows nothing
    """

    def __init__(self, graph: RouteMemory, fixed_action: int = FIXED_ACTION) -> None:
        self.graph = graph
        self.fixed_action = fixed_action
        # The exploration path being driven: the states it expects to pass and the action at each
        self._path: list[tuple[int, int]] = []

    def act(self, observation: Any) -> int:
        """The training action at one (unbatched) observation."""
        batch = batch_of_one(observation)
        state = int(self.graph.states_of(batch, add=True)[0])
        if not (self._path and self._path[0][0] == state):
            slots = self.graph.path_to_untried(state)
            if slots is None:
                self._path = []
                route = int(self.graph.route_actions(batch)[0])
                return route if route >= 0 else self.fixed_action
            self._path = self._states_along(state, slots)
        return int(self.graph.slot_actions(batch, np.array([self._path.pop(0)[1]]))[0])

    def _states_along(self, state: int, slots: list[int]) -> list[tuple[int, int]]:
        """The (state, slot) pairs of a path of known edges (its last slot untried)."""
        pairs = []
        for slot in slots:
            pairs.append((state, slot))
            state = int(self.graph.target[state, slot])
        return pairs

    def policy(self, observations: Any) -> np.ndarray:
        """The greedy batch policy that is evaluated: plan, else explore, else the fixed action."""
        actions = self.graph.route_actions(observations)
        unplanned = actions < 0
        if unplanned.any():
            actions[unplanned] = self.graph.explore_actions(select_rows(observations, unplanned))
        actions[actions < 0] = self.fixed_action
        return actions


def floor_steps(
    env: CampusNavEnv,
    seed: int,
    eval_every: int,
    max_env_steps: int | None = None,
    memory: str = "places",
    sample: int | None = None,
) -> FloorResult:
    """
    Run the experience-graph agent on ``env`` until its greedy policy solves the map (or ``max_env_steps``).

    :param env: The environment (its goals, closures and ``max_steps`` apply)
    :param seed: Seed of the env's starts (the agent itself is deterministic)
    :param eval_every: Env steps between evaluations
    :param max_env_steps: Step cap (default: 200 steps per (observation, action) pair, far beyond need)
    :param memory: ``"places"`` (the env's declared frame) or ``"poses"`` (exact observations)
    :param sample: Check a seeded sample of this many (start, heading) pairs at each evaluation and every pair only
        once the sample is at the bar (a large city); None: every pair at every evaluation
    :return: the run's figures
    """
    if eval_every < 1:
        raise ValueError(f"eval_every must be at least 1, got {eval_every}")
    if memory not in MEMORIES:
        raise ValueError(f"memory must be one of {MEMORIES}, got {memory!r}")
    # The floor keeps exact observations: its places are told apart bit for bit, as the fixed views repeat
    graph = RouteMemory.for_env(env, place_frame="auto" if memory == "places" else None, recognition="exact")
    agent = FloorAgent(graph)
    driven = entered_states(env)  # for the report only: the agent is never told
    cap = max_env_steps if max_env_steps is not None else 200 * env.graph.transition_table.size
    start = time.perf_counter()
    evaluation_seconds = 0.0
    steps = episodes = evaluations = 0
    evaluation: RouteEvaluation | None = None
    driven_solved: tuple[int, int] | None = None
    solved = False
    observation, _ = env.reset(seed=seed)
    while steps < cap and not solved:
        episodes += 1
        done = False
        while not done and steps < cap:
            action = agent.act(observation)
            next_observation, reward, terminated, truncated, info = env.step(action)
            graph.add(observation, action, next_observation, float(reward), terminated, info.get("is_success"))
            steps += 1
            observation, done = next_observation, terminated or truncated
            if steps % eval_every == 0:
                began = time.perf_counter()
                report = evaluate_routes(env, agent.policy, sample=sample, seed=evaluations, keep_nodes=False)
                if report.is_sample and is_solved(RouteEvaluation(steps, episodes, 0.0, report)):
                    report = evaluate_routes(env, agent.policy, keep_nodes=False)  # only every pair counts
                evaluation_seconds += time.perf_counter() - began
                evaluations += 1
                evaluation = RouteEvaluation(steps, episodes, time.perf_counter() - start, report)
                if driven_solved is None and is_solved(routes_from(evaluation, env, driven)):
                    driven_solved = steps, episodes
                solved = is_solved(evaluation)
                if solved:
                    break
        if done:
            observation, _ = env.reset()
    return FloorResult(
        solved=solved,
        env_steps=steps,
        episodes=episodes,
        wall_seconds=time.perf_counter() - start,
        evaluation_seconds=evaluation_seconds,
        evaluations=evaluations,
        success=evaluation.success_rate if evaluation else 0.0,
        spl=evaluation.spl if evaluation else 0.0,
        states=graph.n_states,
        tried=graph.n_tried,
        driven_solved_steps=driven_solved[0] if driven_solved else None,
        driven_solved_episodes=driven_solved[1] if driven_solved else None,
    )


def entered_states(env: CampusNavEnv) -> np.ndarray:
    """Whether a move leads to each state (node, heading); the others the agent sees only as an episode's start."""
    table = env.graph.transition_table
    entered = np.zeros(table.shape[0], dtype=bool)
    entered[table[table >= 0]] = True
    return entered


def start_only_states(env: CampusNavEnv) -> int:
    """States no move leads to, the goal's excluded: seeing them all waits on the env's random starts."""
    goal_states = np.isin(env.graph.map.state_nodes, env.goal_nodes)
    return int((~entered_states(env) & ~goal_states).sum())


def routes_from(evaluation: RouteEvaluation, env: CampusNavEnv, starts: np.ndarray) -> RouteEvaluation:
    """The evaluation's routes from the start states marked in ``starts`` only."""
    state_of = env.graph.map.state_of
    kept = [route for route in evaluation.report.routes if starts[state_of[route.start, route.heading]]]
    return replace(evaluation, report=RouteReport(kept))


def make_env(n_nodes: int, map_seed: int = 0) -> CampusNavEnv:
    """
    The floor's env: the generated map of ``n_nodes`` (the built-in campus at 101, map seed 0), goal Dreese Lab,
    pixels. ``map_seed``: the city's (``CampusNavCity-v0``'s ``map_seed``); 0 is the maps of the scale benchmarks.
    """
    from campusnav_env.maps.campus import generate_city

    world = make_graph(n_nodes, "scaled") if map_seed == 0 else generate_city(n_nodes, seed=map_seed)
    return CampusNavEnv(world=world, goals=GOAL, **with_view_build(env_kwargs_for(PIXELS), progress=False))


def run_one(
    n_nodes: int,
    seed: int,
    eval_every: int,
    quick: bool,
    max_env_steps: int | None = None,
    env: CampusNavEnv | None = None,
    map_seed: int = 0,
    memory: str = "places",
    sample: int | None = None,
) -> dict[str, Any]:
    """One run as a JSON-lines record (``env``: the size's env on that map seed, if already built; ``sample``: as
    :func:`floor_steps`'s)."""
    env = make_env(n_nodes, map_seed) if env is None else env
    result = floor_steps(env, seed, eval_every, max_env_steps, memory, sample)
    return {
        "memory": memory,
        "size": n_nodes,
        "map_seed": map_seed,
        "seed": seed,
        "eval_every": eval_every,
        "quick": quick,
        "max_env_steps": max_env_steps,
        "state_actions": int(env.graph.transition_table.size),
        "start_only_states": start_only_states(env),
        **asdict(result),
    }


def floor_table(runs: list[dict[str, Any]]) -> list[str]:
    """One row per (memory, size, map seed, eval_every): median and range over seeds."""
    groups: dict[tuple[str, int, int, int], list[dict[str, Any]]] = {}
    for run in sorted(runs, key=lambda r: (memory_of(r), r["size"], r.get("map_seed", 0), r["eval_every"], r["seed"])):
        groups.setdefault((memory_of(run), run["size"], run.get("map_seed", 0), run["eval_every"]), []).append(run)
    rows = []
    for (memory, size, map_seed, eval_every), group in groups.items():
        solved = [r for r in group if r["solved"]]
        steps = [r["env_steps"] for r in solved]
        rows.append([
            memory, f"{size:,}", str(map_seed), f"{group[0]['state_actions']:,}",
            f"{group[0]['start_only_states']:,}", f"{eval_every:,}",
            " ".join(str(r["seed"]) for r in group),
            f"{len(solved)}/{len(group)}",
            _median_range(steps), _median_range([r["episodes"] for r in solved]),
            _median_range([r["driven_solved_steps"] for r in group if r["driven_solved_steps"] is not None]),
            " ".join(f"{r['env_steps']:,}" + ("" if r["solved"] else " (cap)") for r in group),
            _median_range([r["tried"] for r in group]),
            _median_range([r["wall_seconds"] for r in group], 1),
            _median_range([r["evaluation_seconds"] for r in group], 1),
        ])  # fmt: skip
    header = [
        "memory",
        "intersections",
        "map seed",
        "(node, heading, action) triples",
        "start-only states",
        "eval every",
        "seeds",
        "solved",
        "env steps to solved",
        "episodes to solved",
        "env steps to solved, driven-to states only",
        "env steps per seed (cap: not solved by then)",
        "pairs tried",
        "wall s",
        "of which eval s",
    ]
    return markdown_table(header, rows)


def memory_of(run: dict[str, Any]) -> str:
    """The run's memory (runs from before places were pose runs)."""
    return str(run.get("memory", "poses"))


def run_key(run: dict[str, Any]) -> tuple[Any, ...]:
    """What tells a run apart: memory, size, map seed, seed, evaluation period, smoke run, step cap."""
    fields = (run["size"], run.get("map_seed", 0), run["seed"], run["eval_every"], run["quick"], run["max_env_steps"])
    return (memory_of(run), *fields)


def _median_range(values: list[float], digits: int = 0) -> str:
    """``median (min-max)``, ``-`` where there are none."""
    if not values:
        return "-"
    low, high = fmt(min(values), digits), fmt(max(values), digits)
    middle = fmt(statistics.median(values), digits)
    return middle if low == high else f"{middle} ({low}-{high})"


def write_report(runs: list[dict[str, Any]], out: Path, argv: list[str] | None) -> None:
    machine = measured_on(out, machine_line(RUNS_LINE))
    lines = [
        "# The experience-graph floor: env steps to solved",
        "",
        "An agent told only observations, rewards and terminations keeps every transition in a graph over exact "
        "observations, explores to the nearest untried (observation, action) and plans shortest routes over what it "
        f"saw (`benchmarks/experience_graph_floor.py`). Solved: {solved_bar()} from every (start, heading), goal "
        f"{GOAL}, evaluated every `eval every` env steps (steps to solved are exact to within that). Episodes from the "
        "env's random starts, capped at its `max_steps`. Features: 64x48 pixel features. Start-only states: (node, "
        "heading) pairs no move leads to (a move leaves the agent facing away from the road it came along), seen only "
        "as an episode's random start; an agent that does not generalise across observations has to wait for each "
        "of them, so the last column scores the same evaluations on the routes from the other starts only. Median "
        "(range) over seeds; wall time includes the evaluations, not the env build.",
        "",
        machine,
        "",
        *floor_table(runs),
    ]
    publish(out, lines, "experience_graph_floor.py", argv)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", nargs="+", type=int, help="intersections (default 101 1000; 101 with --quick)")
    parser.add_argument("--seeds", nargs="+", type=int, help="seeds of the starts (default 0 1 2; 0 with --quick)")
    parser.add_argument("--eval-every", type=int, help="env steps between evaluations (default: by size)")
    parser.add_argument("--max-env-steps", type=int, help="step cap per run (default: 200 per (state, action) pair)")
    parser.add_argument("--quick", action="store_true", help="smoke run: 101 nodes, seed 0")
    parser.add_argument("--map-seed", type=int, default=0, help="seed of the generated city (CampusNavCity's map_seed)")
    parser.add_argument("--memory", nargs="+", choices=MEMORIES, default=["places"], help="what the agent knows")
    parser.add_argument("--runs-file", type=Path, default=RESULTS_DIR / "experience_graph_floor_runs.jsonl")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "experience_graph_floor.md")
    args = parser.parse_args(argv)
    sizes = args.sizes or ([101] if args.quick else [101, 1000])
    seeds = args.seeds or ([0] if args.quick else [0, 1, 2])
    # One env per map, built when its first run is due (the jobs come map by map)
    env_of = functools.lru_cache(maxsize=1)(make_env)
    jobs = [
        (memory, size, seed, args.eval_every or default_eval_every(size))
        for size in sizes
        for memory in args.memory
        for seed in seeds
    ]

    def run_job(job: tuple[str, int, int, int]) -> dict[str, Any]:
        memory, size, seed, eval_every = job
        env = env_of(size, args.map_seed)
        return run_one(size, seed, eval_every, args.quick, args.max_env_steps, env, args.map_seed, memory)

    def describe(record: dict[str, Any]) -> str:
        return (
            f"{memory_of(record)}, {record['size']} nodes seed {record['seed']}: "
            f"{'solved' if record['solved'] else 'NOT solved'} at {record['env_steps']:,} env steps, "
            f"{record['episodes']:,} episodes, {record['wall_seconds']:.1f} s "
            f"(success {record['success']:.3f}, SPL {record['spl']:.3f})"
        )

    runs = run_missing(
        args.runs_file,
        jobs,
        run_job,
        key=run_key,
        job_key=lambda job: (*job[:2], args.map_seed, *job[2:], args.quick, args.max_env_steps),
        describe=describe,
    )
    write_report(runs.records, args.out, argv)


if __name__ == "__main__":
    main()
