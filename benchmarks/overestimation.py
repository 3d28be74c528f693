"""Over-estimation: the agents' Q estimates against the exact Q* of the map, before and after a road closes.

CampusNav is a known, deterministic MDP, so the optimal action values Q* are exact
(:func:`campusnav_env.optimal_values.optimal_q_values`, value iteration with the agent's gamma and the env's rewards).
Every ``--every`` env steps each agent's Q is compared with Q* on

- *all pairs*: every (state, action) of the states not at the goal (blocked actions and states never visited
  included);
- *visited pairs*: the distinct (state, action) pairs in the agent's replay buffer (what its loss is fitted on),
  found by mapping the stored observations back to states (``CampusNavEnv.states_of``).

The figures are the mean signed error ``Q - Q*`` (> 0: over-estimation), the mean absolute error, and the greedy
value's error ``max_a Q(s, a) - V*(s)`` averaged over states (the value a max-based target bootstraps from, where
over-estimation bias shows). The agent's Q is what it acts on: the mean of DCQN's two critics, DQN's one critic; for
DCQN the minimum over its critics is recorded too (the pessimistic value its target takes, here of the online
critics).

Agents (``--agents``): ``DCQN`` as shipped (``hyperparams/dcqn.yml``), ``DCQN, single-critic target`` (the same with
``pessimistic_target=False``: the target takes the first target critic instead of the minimum), ``DCQN, no
heading_key`` and ``DCQN, no heading_key, single-critic target`` (the critics read the heading as an input: DQN's
network) and ``DQN`` (SB3's DQN, same settings and network). Each trains ``--steps`` env steps (phase 1), then the
busiest road on the shortest routes to the goal closes (the first closure of ``closures_one_at_a_time.py``), Q* is
recomputed on the closed map, and training goes on for ``--after`` steps (phase 2) with the same measurements against
the new Q*: the stale values right after the closure, then how they come down.

Runs go to ``--workers`` worker processes (default: one per core; one torch thread each); each finished run is
appended to a JSON-lines file, so an interrupted benchmark keeps its runs and a rerun skips them. Writes
``results/overestimation.md`` and ``results/overestimation.png`` (errors vs env steps per agent, the closure marked).

Usage::

    python benchmarks/overestimation.py                 # 5 agents, seeds 0 1 2, 20k + 10k steps (~7 min, 2 cores)
    python benchmarks/overestimation.py --agents DCQN DQN --seeds 0 1 --steps 30000 --after 15000
    python benchmarks/overestimation.py --quick --out /tmp/o.md --runs-file /tmp/o.jsonl   # smoke run (~1 minute)
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from matplotlib.figure import Figure
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback

from benchmarks.campusnav_runs import TASKS, VARIANTS, Variant, quick_env_kwargs
from benchmarks.closure_runs import busiest_closures
from benchmarks.report import RESULTS_DIR, machine_line, publish, run_missing
from benchmarks.workers import workers_argument
from campusnav_env.env import CampusNavEnv
from campusnav_env.figures import figure_image, write_figure
from campusnav_env.optimal_values import optimal_q_values
from campusnav_env.route_evaluation import evaluate_routes
from sb3_dcqn.zoo_entry import ZooEntry

SCRIPT = "overestimation.py"
Road = tuple[int, int]

SINGLE = {"pessimistic_target": False}
AGENTS: dict[str, Variant] = {
    "DCQN": VARIANTS["DCQN"],
    "DCQN, single-critic target": Variant("DCQN, single-critic target", overrides=SINGLE),
    "DCQN, no heading_key": VARIANTS["DCQN, no heading_key"],
    "DCQN, no heading_key, single-critic target": Variant(
        "DCQN, no heading_key, single-critic target", policy_overrides={"heading_key": None}, overrides=SINGLE
    ),
    "DQN": VARIANTS["DQN"],
}
QUICK_AGENTS = ("DCQN", "DCQN, single-critic target", "DQN")
PHASES = ("before", "after")
PHASE_NAMES = {"before": "training", "after": "after the closure"}
# Pairs whose Q* the closure changed: anything above value iteration's tolerance
CHANGED_TOLERANCE = 1e-6


# --------------------------------------------------------------------------------------------- the measurements
def value_errors(
    q: np.ndarray, q_star: np.ndarray, states: np.ndarray, masks: Mapping[str, np.ndarray] | None = None
) -> dict[str, float | None]:
    """
    How far a Q table is from Q*: mean signed and absolute errors over pairs, and the greedy value's error.

    :param q: Estimated values, ``(S, A)``
    :param q_star: The exact values, ``(S, A)``
    :param states: The states measured (indices or a boolean mask over S), e.g. those not at the goal
    :param masks: Named boolean ``(S, A)`` masks of pairs to measure besides all pairs (e.g. ``"visited"``)
    :return: ``signed_all``, ``abs_all`` (over every pair of ``states``), ``greedy`` (mean over ``states`` of
        ``max_a q - max_a q_star``), and for each mask ``signed_<name>``, ``abs_<name>`` (``None`` where the mask
        selects no pair of ``states``) and ``fraction_<name>`` (its share of the pairs)
    """
    q_rows, star_rows = np.asarray(q, dtype=np.float64)[states], np.asarray(q_star, dtype=np.float64)[states]
    error = q_rows - star_rows
    result: dict[str, float | None] = {
        "signed_all": float(error.mean()),
        "abs_all": float(np.abs(error).mean()),
        "greedy": float((q_rows.max(axis=1) - star_rows.max(axis=1)).mean()),
    }
    for name, mask in (masks or {}).items():
        selected = np.asarray(mask, dtype=bool)[states]
        some = bool(selected.any())
        result[f"signed_{name}"] = float(error[selected].mean()) if some else None
        result[f"abs_{name}"] = float(np.abs(error[selected]).mean()) if some else None
        result[f"fraction_{name}"] = float(selected.mean())
    return result


def agent_q_values(model: BaseAlgorithm, env: CampusNavEnv, goal: int) -> np.ndarray:
    """
    Every critic's Q of every state of the map (states at the goal included), heading for ``goal``.

    :param model: A DCQN (its critics) or an SB3 DQN (its one critic)
    :param env: The env the model trains on
    :param goal: The goal node
    :return: ``(n_critics, S, A)`` (``n_critics = 1`` for DQN)
    """
    states = np.arange(env.graph.n_states)
    observations = env.observations_at(env.graph.map.state_nodes[states], env.graph.map.state_headings[states], goal)
    tensors, _ = model.policy.obs_to_tensor(observations)
    q_net = model.q_net  # type: ignore[attr-defined]
    with th.no_grad():
        q = q_net.critic_values(tensors) if hasattr(q_net, "critic_values") else q_net(tensors)[None]
    return q.cpu().numpy().astype(np.float64)


def visited_pairs(buffer: ReplayBuffer, env: CampusNavEnv) -> np.ndarray:
    """
    The (state, action) pairs of the transitions stored in a replay buffer.

    SB3's dict buffers keep arrays of shape ``(buffer_size, n_envs, ...)``, filled up to ``pos`` (all of them once
    ``full``); the stored observations are mapped back to states with :meth:`CampusNavEnv.states_of`.

    :param buffer: A replay buffer with dict observations (SB3's ``DictReplayBuffer`` or DCQN's)
    :param env: The env whose views the observations show
    :return: Boolean ``(S, A)``: True where the buffer holds a transition from that state with that action
    """
    if not isinstance(buffer.observations, dict):
        raise ValueError("visited_pairs needs a buffer of dict (feature) observations")
    filled = buffer.buffer_size if buffer.full else buffer.pos
    visited = np.zeros((env.graph.n_states, env.graph.map.n_actions), dtype=bool)
    if filled == 0:
        return visited
    observations = {
        key: value[:filled].reshape(filled * buffer.n_envs, *value.shape[2:])
        for key, value in buffer.observations.items()
    }
    actions = buffer.actions[:filled].reshape(filled * buffer.n_envs).astype(np.int64)
    visited[env.states_of(observations), actions] = True
    return visited


def measure(
    model: BaseAlgorithm, env: CampusNavEnv, goal: int, q_star: np.ndarray, changed: np.ndarray | None = None
) -> dict[str, float | None]:
    """
    One measurement of an agent against Q*: errors of the Q it acts on (mean of the critics) and of the minimum over
    its critics, greedy route success and SPL from every (start, heading), and the critics' disagreement.

    :param model: The agent
    :param env: Its training env (current closures)
    :param goal: The goal node
    :param q_star: Q* of the current map
    :param changed: ``(S, A)`` mask of the pairs whose Q* the closure changed (after a closure), or ``None``
    :return: the figures (keys of :func:`value_errors`; ``min_`` prefixed for the minimum over critics)
    """
    states = np.flatnonzero(env.graph.map.state_nodes != goal)
    critics = agent_q_values(model, env, goal)
    masks = {"visited": visited_pairs(model.replay_buffer, env)}  # type: ignore[arg-type]
    if changed is not None:
        masks["changed"] = changed
    result = value_errors(critics.mean(axis=0), q_star, states, masks)
    pessimistic = value_errors(critics.min(axis=0), q_star, states, {"visited": masks["visited"]})
    result.update({f"min_{key}": value for key, value in pessimistic.items() if not key.startswith("fraction")})
    result["critic_spread"] = float((critics.max(axis=0) - critics.min(axis=0))[states].mean())
    report = evaluate_routes(env, lambda observations: model.predict(observations, deterministic=True)[0])
    result["success"], result["spl"] = report.success_rate, report.spl
    return result


class ErrorTracker(BaseCallback):
    """
    Measures the agent against Q* every ``every`` env steps of one ``learn()`` call (see :func:`measure`).

    :param env: The training env
    :param goal: The goal node
    :param q_star: Q* of the map during this call
    :param every: Env steps between measurements
    :param phase: Name of the phase recorded with each measurement
    :param changed: Pairs whose Q* the closure changed (phase after a closure)
    """

    def __init__(
        self,
        env: CampusNavEnv,
        goal: int,
        q_star: np.ndarray,
        every: int,
        phase: str,
        changed: np.ndarray | None = None,
    ) -> None:
        super().__init__()
        self.env, self.goal, self.q_star, self.every, self.phase, self.changed = (
            env,
            goal,
            q_star,
            every,
            phase,
            changed,
        )
        self.points: list[dict[str, Any]] = []
        self._start = 0

    def record(self, model: BaseAlgorithm, step: int) -> None:
        point = measure(model, self.env, self.goal, self.q_star, self.changed)
        self.points.append({"phase": self.phase, "step": step, **point})

    def _on_training_start(self) -> None:
        self._start = self.model.num_timesteps

    def _on_step(self) -> bool:
        step = self.model.num_timesteps - self._start
        if step % self.every == 0:
            self.record(self.model, step)
        return True

    def _on_training_end(self) -> None:
        # The end of the phase is always measured, also when it is not a multiple of ``every``
        step = self.model.num_timesteps - self._start
        if not self.points or self.points[-1]["step"] != step:
            self.record(self.model, step)


# ---------------------------------------------------------------------------------------------------- one run
@dataclass(frozen=True)
class Job:
    """
    One agent's run: ``steps`` env steps of training, a closure, ``after`` more steps.

    :param agent: Key of :data:`AGENTS`
    :param seed: Seed of the agent
    :param steps: Env steps before the closure
    :param after: Env steps after the closure
    :param every: Env steps between measurements
    :param closure: The road that closes
    :param quick: Smoke-run settings (pixel features, learning from the first steps)
    """

    agent: str
    seed: int
    steps: int
    after: int
    every: int
    closure: Road
    quick: bool = False


def make_agent(job: Job) -> tuple[BaseAlgorithm, CampusNavEnv]:
    """The job's agent and its training env (the shipped CampusNav-v0 entry, the agent's changes)."""
    # The task's step cap is phase 1: the entry keeps the YAML's exploration steps (9k) within it
    task = dataclasses.replace(TASKS["campus"], max_steps=job.steps)
    variant = AGENTS[job.agent]
    entry = variant.entry(task)
    env_kwargs: dict[str, Any] = {}
    if job.quick:
        # A few hundred steps: learn from a quarter of them on, so that the smoke run trains too
        hyperparams = {
            **entry.hyperparams,
            "learning_starts": min(entry.hyperparams["learning_starts"], job.steps // 4),
        }
        entry = ZooEntry(entry.n_timesteps, hyperparams, entry.env_kwargs, entry.n_envs, entry.callbacks)
        env_kwargs = quick_env_kwargs()
    env = task.make_env(entry, **env_kwargs)
    return variant.make_model(env, entry, job.seed), env.unwrapped  # type: ignore[return-value]


def q_star_of(env: CampusNavEnv, goal: int, gamma: float) -> np.ndarray:
    """Q* of the env's current map with its rewards."""
    return optimal_q_values(env.graph, goal, gamma, env.goal_reward, env.step_penalty, env.collision_penalty)


def run_one(job: Job) -> dict[str, Any]:
    """Train one agent, close the road, train on; measure against Q* all along. Returns the run's record."""
    begin = time.perf_counter()
    model, env = make_agent(job)
    goal = env.goal_nodes[0]
    q_star = q_star_of(env, goal, model.gamma)
    before = ErrorTracker(env, goal, q_star, job.every, "before")
    before.record(model, 0)
    model.learn(job.steps, callback=before)
    env.close_road(*job.closure)
    q_star_closed = q_star_of(env, goal, model.gamma)
    changed = np.abs(q_star_closed - q_star) > CHANGED_TOLERANCE
    after = ErrorTracker(env, goal, q_star_closed, job.every, "after", changed)
    after.record(model, 0)  # the stale values, right after the closure
    model.learn(job.after, callback=after, reset_num_timesteps=False)
    states = env.graph.map.state_nodes != goal
    return {
        **dataclasses.asdict(job),
        "closure": list(job.closure),
        "changed_pairs": int(changed[states].sum()),
        "changed_states": int(changed[states].any(axis=1).sum()),
        "points": [*before.points, *after.points],
        "wall_seconds": round(time.perf_counter() - begin, 1),
    }


# ------------------------------------------------------------------------------------------------------ tables
def _points(runs: Sequence[dict[str, Any]], agent: str, phase: str, step: int) -> list[dict[str, Any]]:
    return [p for r in runs if r["agent"] == agent for p in r["points"] if p["phase"] == phase and p["step"] == step]


def _spread(values: Sequence[float | None], digits: int = 3, signed: bool = True) -> str:
    """A cell: mean ± standard deviation over seeds (``-`` where nothing was measured)."""
    values = [v for v in values if v is not None]
    if not values:
        return "-"
    mean = float(np.mean(values))
    text = f"{mean:+.{digits}f}" if signed else f"{mean:.{digits}f}"
    if len(values) > 1:
        text += f" ± {float(np.std(values, ddof=1)):.{digits}f}"
    return text


def milestones(measured: Sequence[int], total: int, phase: str) -> list[int]:
    """
    The steps of a phase shown in the table: near 10%, 25%, 50% and 100% of the phase (and, after the closure, its
    first two measurements: the stale values and the first ones after training on them).
    """
    measured = sorted(set(measured))
    if not measured:
        return []
    picks = {min(measured, key=lambda s: abs(s - fraction * total)) for fraction in (0.1, 0.25, 0.5, 1.0)}
    if phase == "after":
        picks |= set(measured[:2])
    return sorted(picks)


COLUMNS = (
    ("success", "greedy success", False),
    ("signed_all", "Q - Q*, all pairs", True),
    ("signed_visited", "Q - Q*, visited pairs", True),
    ("abs_all", "abs error, all pairs", False),
    ("greedy", "max Q - V*", True),
    ("min_signed_all", "min over critics: Q - Q*, all pairs", True),
    ("min_greedy", "min over critics: max Q - V*", True),
    ("signed_changed", "Q - Q*, pairs the closure changed", True),
)


def detail_table(runs: Sequence[dict[str, Any]], agents: Sequence[str], steps: int, after: int) -> list[str]:
    """One row per (agent, phase, milestone step): each figure's mean ± sd over seeds."""
    lines = [
        "| agent | phase | step | seeds | " + " | ".join(title for _, title, _ in COLUMNS) + " |",
        "|---|---|---|---|" + "---|" * len(COLUMNS),
    ]
    for agent in agents:
        mine = [r for r in runs if r["agent"] == agent]
        for phase, total in zip(PHASES, (steps, after), strict=True):
            measured = [p["step"] for r in mine for p in r["points"] if p["phase"] == phase]
            for step in milestones(measured, total, phase):
                points = _points(mine, agent, phase, step)
                cells = [_spread([p.get(key) for p in points], signed=signed) for key, _, signed in COLUMNS]
                lines.append(f"| {agent} | {PHASE_NAMES[phase]} | {step} | {len(points)} | {' | '.join(cells)} |")
    return lines


def summary_table(runs: Sequence[dict[str, Any]], agents: Sequence[str], steps: int, after: int) -> list[str]:
    """The headline per agent: end of training, right after the closure, end of the run (mean ± sd over seeds)."""
    lines = [
        f"| agent | seeds | end of training ({steps} steps): success | Q - Q*, all | Q - Q*, visited | max Q - V* | "
        f"right after the closure: Q - Q*, changed pairs | max Q - V* | {after} steps later: success | Q - Q*, "
        "changed pairs | max Q - V* |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for agent in agents:
        mine = [r for r in runs if r["agent"] == agent]
        if not mine:
            continue
        end = _points(mine, agent, "before", steps)
        stale = _points(mine, agent, "after", 0)
        last = _points(mine, agent, "after", after)

        def cells(points: list[dict[str, Any]], keys: Sequence[str]) -> list[str]:
            return [_spread([p.get(k) for p in points], signed=k != "success") for k in keys]

        row = [
            *cells(end, ("success", "signed_all", "signed_visited", "greedy")),
            *cells(stale, ("signed_changed", "greedy")),
            *cells(last, ("success", "signed_changed", "greedy")),
        ]
        lines.append(f"| {agent} | {len(mine)} | {' | '.join(row)} |")
    return lines


# The comparisons that isolate the minimum (same network, same seed: the same initial critics) and the network
PAIRS = (
    ("DCQN", "DCQN, single-critic target"),
    ("DCQN, no heading_key", "DCQN, no heading_key, single-critic target"),
    ("DCQN, no heading_key", "DQN"),
)


def paired_table(runs: Sequence[dict[str, Any]], steps: int, after: int) -> list[str]:
    """
    Differences of ``Q - Q*`` (all pairs) between two agents, paired by seed: mean ± sd over the seeds both ran, at
    the milestones of both phases (< 0: the first agent's Q is lower).
    """
    columns = [("before", step) for step in milestones(_steps_of(runs, "before"), steps, "before")]
    columns += [("after", step) for step in milestones(_steps_of(runs, "after"), after, "after")]
    titles = [f"{'training' if phase == 'before' else 'after the closure'} {step}" for phase, step in columns]
    lines = ["| agent - other agent | seeds | " + " | ".join(titles) + " |", "|---|---|" + "---|" * len(columns)]
    for first, second in PAIRS:
        seconds = {r["seed"]: r for r in runs if r["agent"] == second}
        by_seed = {r["seed"]: (r, seconds[r["seed"]]) for r in runs if r["agent"] == first and r["seed"] in seconds}
        if not by_seed:
            continue
        cells = []
        for phase, step in columns:
            differences = []
            for a, b in by_seed.values():
                x = next((p for p in a["points"] if p["phase"] == phase and p["step"] == step), None)
                y = next((p for p in b["points"] if p["phase"] == phase and p["step"] == step), None)
                if x is not None and y is not None:
                    differences.append(x["signed_all"] - y["signed_all"])
            cells.append(_spread(differences))
        lines.append(f"| {first} - {second} | {len(by_seed)} | {' | '.join(cells)} |")
    return lines


def _steps_of(runs: Sequence[dict[str, Any]], phase: str) -> list[int]:
    return [p["step"] for r in runs for p in r["points"] if p["phase"] == phase]


def diagnostics_table(runs: Sequence[dict[str, Any]], agents: Sequence[str], steps: int) -> list[str]:
    """
    Per agent: how much of the map its buffer covers, how far its critics disagree (the room the minimum has), and
    the largest over-estimation seen during training (each seed's peak over the measurements, mean ± sd).
    """
    half = min(_steps_of(runs, "before") or [0], key=lambda s: abs(s - steps / 2))
    lines = [
        f"| agent | pairs in the buffer at {steps} steps (share) | critics' spread max - min at {half} steps | at "
        f"{steps} steps | peak of Q - Q*, all pairs, during training | peak of max Q - V* during training |",
        "|---|---|---|---|---|---|",
    ]
    for agent in agents:
        mine = [r for r in runs if r["agent"] == agent]
        if not mine:
            continue
        end, middle = _points(mine, agent, "before", steps), _points(mine, agent, "before", half)
        training = [[p for p in r["points"] if p["phase"] == "before"] for r in mine]
        cells = [
            _spread([p["fraction_visited"] for p in end], signed=False),
            _spread([p["critic_spread"] for p in middle], 4, signed=False),
            _spread([p["critic_spread"] for p in end], 4, signed=False),
            _spread([max(p["signed_all"] for p in points) for points in training]),
            _spread([max(p["greedy"] for p in points) for points in training]),
        ]
        lines.append(f"| {agent} | {' | '.join(cells)} |")
    return lines


# ------------------------------------------------------------------------------------------------------ figure
# Zoomed panels: near zero, where over-estimation (rather than the early under-estimation from zero) shows
ZOOM = 0.04
PANELS = (
    ("signed_all", "Q - Q*, all pairs (acted Q: mean of the critics)", None, PHASES),
    ("signed_all", f"the same, zoomed to ±{ZOOM}", ZOOM, PHASES),
    ("greedy", f"max_a Q - V*, mean over states (zoomed to ±{ZOOM})", ZOOM, PHASES),
    ("signed_changed", "after the closure: Q - Q*, pairs whose Q* the closure changed", None, ("after",)),
)


def plot_errors(runs: Sequence[dict[str, Any]], agents: Sequence[str], steps: int, path: Path) -> Path:
    """Signed errors vs env steps, one line per agent (mean over seeds, band: min to max), the closure marked."""
    figure = Figure(figsize=(13, 8.5), dpi=100, layout="constrained")
    axes = figure.subplots(2, 2).ravel()
    for axis, (key, title, zoom, phases) in zip(axes, PANELS, strict=True):
        for index, agent in enumerate(agents):
            mine = [r for r in runs if r["agent"] == agent]
            if not mine:
                continue
            shown = [(p["phase"], p["step"]) for p in mine[0]["points"] if p["phase"] in phases]
            by_run = [{(p["phase"], p["step"]): p.get(key) for p in r["points"]} for r in mine]
            values = np.array(
                [[np.nan if run.get(at) is None else run[at] for at in shown] for run in by_run], dtype=float
            )
            x = [step + (steps if phase == "after" else 0) for phase, step in shown]
            colour = f"C{index}"
            axis.plot(x, np.nanmean(values, axis=0), color=colour, label=agent, linewidth=1.6)
            if len(values) > 1:
                axis.fill_between(x, np.nanmin(values, axis=0), np.nanmax(values, axis=0), color=colour, alpha=0.15)
        axis.axhline(0.0, color="black", linewidth=0.8)
        axis.axvline(steps, color="tab:red", linestyle="--", linewidth=1.2, label="road closes")
        if zoom is not None:
            axis.set_ylim(-zoom, zoom)
        axis.set_title(title, fontsize=10)
        axis.set_xlabel("env steps")
        axis.set_ylabel("mean signed error (> 0: over-estimation)" if axis in axes[::2] else "")
        axis.grid(True, alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncols=min(len(labels), 6), fontsize=9, frameon=False)
    return write_figure(path, figure_image(figure))


# -------------------------------------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--agents", nargs="+", choices=list(AGENTS), default=None, help="default: all five")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--steps", type=int, default=20_000, help="env steps of training before the closure")
    parser.add_argument("--after", type=int, default=10_000, help="env steps of training after the closure")
    parser.add_argument("--every", type=int, default=1_000, help="env steps between measurements")
    parser.add_argument("--quick", action="store_true", help="smoke run: pixel features, 400 + 200 steps, 1 seed")
    parser.add_argument("--out", type=Path, default=None, help="results file (default results/overestimation.md)")
    parser.add_argument("--runs-file", type=Path, default=None, help="default: <out stem>_runs.jsonl beside it")
    workers_argument(parser, default=None)
    args = parser.parse_args(argv)
    th.set_num_threads(1)

    agents = list(args.agents or (QUICK_AGENTS if args.quick else AGENTS))
    steps, after, every, seeds = args.steps, args.after, args.every, args.seeds
    if args.quick:
        steps, after, every, seeds = min(steps, 400), min(after, 200), min(every, 100), seeds[:1]
    out: Path = args.out or RESULTS_DIR / ("overestimation_quick.md" if args.quick else "overestimation.md")
    runs_file: Path = args.runs_file or out.with_name(f"{out.stem}_runs.jsonl")

    # The closure: the road most used by the shortest routes to the goal (chosen from the map, same for every agent)
    probe_job = Job(agents[0], seeds[0], steps, after, every, (0, 0), args.quick)
    probe_model, probe = make_agent(probe_job)
    goal = probe.goal_nodes[0]
    closure = busiest_closures(probe.graph, goal, 1)[0]
    q_star = q_star_of(probe, goal, probe_model.gamma)
    probe.close_road(*closure)
    q_star_closed = q_star_of(probe, goal, probe_model.gamma)
    gamma = probe_model.gamma
    explore_steps = round(probe_model.exploration_fraction * steps)
    del probe_model
    print(f"closure: road {closure[0]}-{closure[1]} (goal node {goal})", flush=True)

    settings = {"steps": steps, "after": after, "every": every, "quick": args.quick, "closure": list(closure)}
    jobs = [Job(agent, seed, steps, after, every, closure, args.quick) for seed in seeds for agent in agents]

    def describe(record: dict[str, Any]) -> str:
        end = next(p for p in record["points"] if p["phase"] == "before" and p["step"] == steps)
        return (
            f"{record['agent']}, seed {record['seed']}: at {steps} steps success {end['success']:.3f}, Q - Q* "
            f"{end['signed_all']:+.4f} (visited {end['signed_visited']:+.4f}), max Q - V* {end['greedy']:+.4f}; "
            f"{record['wall_seconds']:.0f} s"
        )

    ran = run_missing(
        runs_file,
        jobs,
        run_one,
        key=lambda r: (r["agent"], r["seed"]),
        job_key=lambda job: (job.agent, job.seed),
        settings=settings,
        workers=args.workers,
        describe=describe,
    )
    stored = ran.records

    shown = [a for a in AGENTS if a in agents or any(r["agent"] == a and r["seed"] in seeds for r in stored)]
    runs = [r for r in stored if r["agent"] in shown and r["seed"] in seeds]
    picture = plot_errors(runs, shown, steps, out.with_suffix(".png"))
    states = np.flatnonzero(probe.graph.map.state_nodes != goal)
    v_star = q_star[states].max(axis=1)
    changed = np.abs(q_star_closed - q_star)[states] > CHANGED_TOLERANCE
    wall = [r["wall_seconds"] for r in runs]
    workers = "one after another in one process" if args.workers == 1 else f"in {args.workers} worker processes"
    lines = [
        "# Over-estimation: the agents' Q against the exact Q*, before and after a road closes",
        "",
        machine_line(f"runs {workers}"),
        "",
        "**Q\\*** is the exact optimal action value of the map: CampusNav is a known, deterministic MDP, so value "
        f"iteration gives Q*(s, a) for every (intersection, heading) state and action (gamma = {gamma}, the agents' "
        "own; rewards +1 at the goal, -0.005 per step, -0.01 for a blocked move; "
        "`campusnav_env.optimal_values.optimal_q_values`). It is what a critic's Q(s, a) estimates. "
        f"On this map V*(s) = max_a Q*(s, a) ranges from {v_star.min():.3f} to {v_star.max():.3f} "
        f"(mean {v_star.mean():.3f}) over the {states.size} states not at the goal.",
        "",
        "How to read it: **Q - Q\\*** is the mean signed error (> 0: the agent over-estimates, < 0: under-estimates); "
        f"*all pairs* are the {states.size * q_star.shape[1]} (state, action) pairs of those states, blocked actions "
        "and never-visited states included; *visited pairs* are the distinct (state, action) pairs in the agent's "
        "replay buffer (what its loss is fitted on); **max Q - V\\*** is the error of the greedy value, averaged over "
        "states: what a max-based target bootstraps from, where the over-estimation bias of the max shows. The "
        "agent's Q is the one it acts on: the mean of DCQN's two critics, DQN's single critic; *min over critics* is "
        "the pessimistic value (DCQN's target takes the minimum of its target critics; measured here on the online "
        "critics; for DQN it is its one critic). Each cell: mean ± standard deviation over seeds.",
        "",
        f"Setup: CampusNav-v0 (goal Dreese Lab, node {goal}), the shipped DCQN entry (`hyperparams/dcqn.yml`: "
        f"{'pixel features of 64x48 views (smoke run)' if args.quick else 'EfficientNet-Lite0 features'} projected to "
        "64 per view, lr 3e-4, target update every 500 steps, epsilon-greedy exploration decaying over "
        f"{explore_steps} steps)"
        f"; {steps} env steps of training, then road {closure[0]}-{closure[1]} closes (the road most used by the "
        "shortest routes to the goal, as in `closures_one_at_a_time.py`; invisible: the agent learns of it by "
        f"bumping into it), Q* is recomputed on the closed map, and training goes on for {after} steps, measured "
        f"against the new Q*. The closure changes Q* of {int(changed.sum())} pairs ({int(changed.any(axis=1).sum())} "
        f"states); *pairs the closure changed* are those. Measurements every {every} env steps; greedy success: "
        "the greedy route from every (start, heading).",
        "",
        "Agents: " + "; ".join(f"**{a}**: {AGENT_NOTES[a]}" for a in shown) + ".",
        "",
        "## Summary",
        "",
        *summary_table(runs, shown, steps, after),
        "",
        "## What the minimum does: differences of Q - Q* (all pairs), paired by seed",
        "",
        "The same seed gives the same initial critics, so each difference isolates the change: the minimum over the "
        "target critics against the first target critic (same network), and DCQN without the heading key against "
        "DQN (same network, two critics and the minimum against one critic). < 0: the first agent's Q is lower.",
        "",
        *paired_table(runs, steps, after),
        "",
        "## Coverage, the critics' disagreement, and the peak over-estimation",
        "",
        "The minimum of two critics can only take off what they disagree on: the critics' spread is the mean over "
        "all pairs of max - min over the critics (0 for DQN's one critic).",
        "",
        *diagnostics_table(runs, shown, steps),
        "",
        "## Over training and after the closure",
        "",
        *detail_table(runs, shown, steps, after),
        "",
        f"![signed errors vs env steps]({picture.name})",
        "",
        f"Time: {len(runs)} runs, {np.sum(wall):.0f} s of run time in all (per run {min(wall, default=0):.0f}-"
        f"{max(wall, default=0):.0f} s, measurements included); " + ran.invocation_text(),
    ]
    publish(out, lines, SCRIPT, argv)


AGENT_NOTES = {
    "DCQN": "as shipped (two critics, target from the minimum of the two target critics, acting on their mean)",
    "DCQN, single-critic target": "`pessimistic_target=False`: the target takes the first target critic instead of "
    "the minimum (both critics still fit it; acting still on the mean)",
    "DCQN, no heading_key": "the critics read the heading as an input (DQN's network), target from the minimum",
    "DCQN, no heading_key, single-critic target": "both changes: DQN's network and target, but two critics fitted to "
    "it and acting on their mean",
    "DQN": "SB3's DQN, same settings and network as `DCQN, no heading_key`, one critic, target `max_a' Q'(s', a')`",
}


if __name__ == "__main__":
    main()
