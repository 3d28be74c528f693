"""Equal-budget comparison: DCQN against target-driven actor-critic, PPO, the DQN family, tabular Q and the optimum.

The paper's claim (Han & Yilmaz, after Zhu et al.'s target-driven navigation): at equal training time, the actor-critic
agent needs 4.5x DCQN's steps to reach a goal. Here every agent trains one model per goal under the same wall-clock
budget of *training* time (route evaluations and env construction excluded, the same harness for every agent), on 14
goals of the campus: the four paper goals, the eight other landmarks, and the two intersections farthest from all
landmarks. Agents:

- ``DCQN``: as shipped (``hyperparams/dcqn.yml``, CampusNav-v0 entry);
- ``A2C (target-driven AC)``: SB3's A2C with the same embedding-fusion extractor (Zhu et al.'s siamese fusion of
  current and goal views), separate actor and critic heads, 4 envs, SB3's A2C defaults (lr 7e-4, 5-step returns)
  with gamma 0.95 and an entropy bonus of 0.01;
- ``PPO``: the same network, 4 envs, 128 steps per env per rollout, 4 epochs, batch 64;
- ``DQN``: SB3's DQN, DCQN's settings and network (without DCQN's heading-relative critics);
- ``QR-DQN``: sb3-contrib's QR-DQN, the same settings and network, 25 quantiles;
- ``tabular Q``: Q-learning on a table of the (intersection, heading) states, told its state by the env (no views):
  the floor of what learning the map costs in steps; learning rate 1 (the map is deterministic), the same
  epsilon-greedy schedule as DCQN;
- ``oracle``: greedy on the exact Q* (value iteration on the known map): the shortest routes, no training.

Evaluation, the same for every agent: the greedy route from every (start, heading) (success, SPL; the first
evaluation at the solved bar, ``sb3_dcqn.campusnav.solved``, gives the time to a solved goal), and 100 test episodes
per goal from random starts (the same starts for every agent: drawn from the goal and the seed), capped at 200
steps, a failed episode counting 200: success, mean steps, SPL. Actor-critic agents are also tested sampling their
actions (Zhu et al.'s agent acts by sampling). Routes are evaluated every ``--eval-every`` env steps during training.

Runs (agent x goal x seed) go to ``--workers`` processes (default: one per core) of one torch thread each; each
finished run is appended to a JSON-lines file, so an interrupted benchmark keeps its results and a rerun skips what is
done. Writes ``results/compare.md`` and ``results/compare.png``.

Usage::

    python benchmarks/compare.py                            # 14 goals, 5 s per goal, seed 0, a worker per core
    python benchmarks/compare.py --budget 20 --seeds 0 1    # the results file's run
    python benchmarks/compare.py --budget 300 --seeds 0 1 2   # the paper's 5 minutes per goal
    python benchmarks/compare.py --quick --out /tmp/compare.md --runs-file /tmp/runs.jsonl   # a smoke run
"""

from __future__ import annotations

import argparse
import statistics
import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from matplotlib.figure import Figure
from sb3_contrib import QRDQN
from stable_baselines3 import A2C, DQN, PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

from benchmarks.campusnav_runs import TASKS, VARIANTS, Task
from benchmarks.report import RESULTS_DIR, machine_line, publish, run_missing
from benchmarks.workers import workers_argument
from campusnav_env.env import CampusNavEnv
from campusnav_env.features.view_build import with_view_build
from campusnav_env.figures import figure_image, write_figure
from campusnav_env.maps.campus import GOALS
from campusnav_env.optimal_values import optimal_q_values
from campusnav_env.route_evaluation import Policy, RouteReport, evaluate_routes
from sb3_dcqn import DCQN
from sb3_dcqn.campusnav.solved import SOLVED_SPL, SOLVED_SUCCESS
from sb3_dcqn.fusion import EmbeddingFusionExtractor

N_GOALS = 14
TEST_EPISODES = 100
TEST_STEP_CAP = 200
PAPER_AC_STEP_RATIO = 4.5
# Long enough never to be reached: the budget ends training (DCQN's exploration is kept at the YAML's steps)
NO_STEP_CAP = 10_000_000
ACTOR_CRITICS = ("A2C (target-driven AC)", "PPO")


# ------------------------------------------------------------------------------------------------------- the goals
def campus_goals(env: CampusNavEnv, count: int = N_GOALS) -> list[str | int]:
    """
    The comparison's goals: the paper's four, then the campus's other landmarks, then the intersections farthest (in
    hops) from every landmark, until there are ``count``.
    """
    landmarks = env.graph.map.landmarks
    goals: list[str | int] = [*GOALS, *(name for name in landmarks if name not in GOALS)][:count]
    if len(goals) < count:
        hops = np.min([env.node_distances(node) for node in landmarks.values()], axis=0).astype(float)
        hops[hops < 0] = -np.inf  # not connected to the landmarks: not a fair goal
        for node in np.argsort(-hops, kind="stable")[: count - len(goals)]:
            goals.append(int(node))
    return goals


def goal_label(goal: str | int) -> str:
    return goal if isinstance(goal, str) else f"node {goal}"


def episode_starts(env: CampusNavEnv, goal: str | int, seed: int, episodes: int = TEST_EPISODES) -> np.ndarray:
    """
    The test episodes' start states: a uniformly random intersection that can reach the goal, then a uniformly
    random heading there (the env's own starting-state distribution). A function of the goal and the seed only, so
    every agent is tested from the same starts.
    """
    goal_node = env.goal_nodes[env._goal_index_of(goal)]
    nodes = np.flatnonzero(env.node_distances(goal_node) > 0)
    label = goal_label(goal)
    rng = np.random.default_rng([seed, zlib.crc32(label.encode())])
    state_of = env.graph.map.state_of
    starts = []
    for node in rng.choice(nodes, size=episodes):
        headings = np.flatnonzero(state_of[node] >= 0)
        starts.append(int(state_of[node, rng.choice(headings)]))
    return np.asarray(starts, dtype=np.int64)


# -------------------------------------------------------------------------------------------- the budget harness
class BudgetHarness:
    """
    The same training budget and the same route evaluations for every agent.

    Training time counts from :meth:`start`, less the time spent in evaluations; :meth:`step` is called after every
    env step (or vector step) of training, evaluates the greedy routes when due and says whether the agent may
    train on.

    :param env: The evaluation env (one goal)
    :param seconds: Training-time budget
    :param eval_every: Evaluate the routes every this many env steps
    """

    def __init__(self, env: CampusNavEnv, seconds: float, eval_every: int) -> None:
        if seconds <= 0 or eval_every < 1:
            raise ValueError(f"need a positive budget and eval_every >= 1, got {seconds}, {eval_every}")
        self.env = env
        self.seconds = seconds
        self.eval_every = eval_every
        self.evaluations: list[dict[str, float]] = []
        self.excluded_seconds = 0.0
        self._start: float | None = None
        self._next_eval = eval_every

    def start(self) -> None:
        self._start = time.perf_counter()

    @property
    def train_seconds(self) -> float:
        assert self._start is not None, "the harness has not started"
        return time.perf_counter() - self._start - self.excluded_seconds

    def step(self, env_steps: int, policy: Policy) -> bool:
        """Evaluate if due; ``True`` while the budget lasts."""
        if env_steps >= self._next_eval:
            while self._next_eval <= env_steps:
                self._next_eval += self.eval_every
            self.evaluate(env_steps, policy)
        return self.train_seconds < self.seconds

    def evaluate(self, env_steps: int, policy: Policy) -> RouteReport:
        """Route evaluation from every start, recorded; its time does not count as training."""
        start = time.perf_counter()
        report = evaluate_routes(self.env, policy)
        self.evaluations.append(
            {"step": env_steps, "seconds": self.train_seconds, "success": report.success_rate, "spl": report.spl}
        )
        self.excluded_seconds += time.perf_counter() - start
        return report

    def solved_at(self) -> dict[str, float] | None:
        """The first evaluation at the thresholds, if any."""
        return next((e for e in self.evaluations if e["success"] >= SOLVED_SUCCESS and e["spl"] >= SOLVED_SPL), None)


class _HarnessCallback(BaseCallback):
    """Hands an SB3 agent's steps to the harness and stops ``learn()`` when the budget is spent."""

    def __init__(self, harness: BudgetHarness) -> None:
        super().__init__()
        self.harness = harness
        self._policy: Policy | None = None

    def _init_callback(self) -> None:
        self._policy = greedy_policy(self.model)  # once, not on every step

    def _on_step(self) -> bool:
        assert self._policy is not None
        return self.harness.step(self.model.num_timesteps, self._policy)


def greedy_policy(model: Any) -> Policy:
    return lambda observations: model.predict(observations, deterministic=True)[0]


def sampling_policy(model: Any) -> Policy:
    return lambda observations: model.predict(observations, deterministic=False)[0]


# ----------------------------------------------------------------------------------------------------- the agents
class TabularQLearning:
    """
    Q-learning on a table of the map's (intersection, heading) states, told its state by the env (``info``).

    :param env: The training env
    :param gamma: Discount factor
    :param explore_steps: Steps over which epsilon falls from 1 to ``final_eps``
    :param final_eps: Exploration after ``explore_steps``
    :param learning_rate: Step size (1 is exact for a deterministic map)
    :param seed: Seed of the exploration and the env
    """

    def __init__(
        self,
        env: CampusNavEnv,
        gamma: float,
        explore_steps: int,
        final_eps: float = 0.05,
        learning_rate: float = 1.0,
        seed: int = 0,
    ) -> None:
        self.env = env
        self.gamma = gamma
        self.explore_steps = explore_steps
        self.final_eps = final_eps
        self.learning_rate = learning_rate
        self.seed = seed
        self.q_table = np.zeros((env.graph.n_states, int(env.action_space.n)))
        self.num_timesteps = 0
        self._rng = np.random.default_rng(seed)

    def _state(self, info: dict[str, Any]) -> int:
        return int(self.env.graph.map.state_of[info["node"], info["heading"]])

    def predict_batch(self, observations: dict[str, np.ndarray]) -> np.ndarray:
        return self.q_table[self.env.states_of(observations)].argmax(axis=1)

    def learn(self, harness: BudgetHarness) -> None:
        _, info = self.env.reset(seed=self.seed)
        state = self._state(info)
        while True:
            eps = max(self.final_eps, 1.0 - (1.0 - self.final_eps) * self.num_timesteps / self.explore_steps)
            values = self.q_table[state]
            if self._rng.random() < eps:
                action = int(self._rng.integers(values.size))
            else:
                action = int(self._rng.choice(np.flatnonzero(values == values.max())))
            _, reward, terminated, truncated, info = self.env.step(action)
            next_state = self._state(info)
            # Timeouts bootstrap, as in SB3's buffers: the step limit is not part of the task
            target = reward + (0.0 if terminated else self.gamma * self.q_table[next_state].max())
            values[action] += self.learning_rate * (target - values[action])
            self.num_timesteps += 1
            if terminated or truncated:
                _, info = self.env.reset()
                next_state = self._state(info)
            state = next_state
            if not harness.step(self.num_timesteps, self.predict_batch):
                return


@dataclass(frozen=True)
class Trained:
    """What an agent leaves for the evaluation: its greedy policy, a sampling one (actor-critics), its env steps."""

    greedy: Policy
    sampling: Policy | None
    env_steps: int


def _fusion_kwargs(task: Task) -> dict[str, Any]:
    """The shipped DCQN entry's embedding-fusion extractor, for the agents that share it."""
    policy_kwargs = VARIANTS["DCQN"].entry(task).hyperparams["policy_kwargs"]
    assert policy_kwargs["features_extractor_class"] is EmbeddingFusionExtractor
    return {
        "features_extractor_class": EmbeddingFusionExtractor,
        "features_extractor_kwargs": dict(policy_kwargs["features_extractor_kwargs"]),
    }


def _value_based(name: str) -> Callable[..., Trained]:
    """DCQN, DQN or QR-DQN with the shipped entry's settings."""

    def train(task: Task, make_env: Callable[[], CampusNavEnv], harness: BudgetHarness, seed: int) -> Trained:
        variant = VARIANTS["DCQN" if name == "DCQN" else "DQN"]
        entry = variant.entry(task)
        hyperparams = dict(entry.hyperparams)
        algo: type[BaseAlgorithm] = {"DCQN": DCQN, "DQN": DQN, "QR-DQN": QRDQN}[name]
        if name == "QR-DQN":
            hyperparams["policy_kwargs"] = {**hyperparams["policy_kwargs"], "n_quantiles": 25}
        model = algo(env=make_env(), seed=seed, device="cpu", **hyperparams)
        return _learn(model, harness, sampling=False)

    return train


def _actor_critic(name: str) -> Callable[..., Trained]:
    """A2C (target-driven actor-critic) or PPO with the embedding-fusion extractor, 4 envs."""

    def train(task: Task, make_env: Callable[[], CampusNavEnv], harness: BudgetHarness, seed: int) -> Trained:
        policy_kwargs = {**_fusion_kwargs(task), "net_arch": {"pi": [128], "vf": [128]}}
        env = make_vec_env(make_env, n_envs=4, seed=seed)
        common = {"gamma": 0.95, "ent_coef": 0.01, "policy_kwargs": policy_kwargs, "seed": seed, "device": "cpu"}
        if name == "PPO":
            model: BaseAlgorithm = PPO("MultiInputPolicy", env, n_steps=128, batch_size=64, n_epochs=4, **common)
        else:
            model = A2C("MultiInputPolicy", env, **common)
        return _learn(model, harness, sampling=True)

    return train


def _learn(model: BaseAlgorithm, harness: BudgetHarness, sampling: bool) -> Trained:
    harness.start()
    model.learn(NO_STEP_CAP, callback=_HarnessCallback(harness))
    return Trained(greedy_policy(model), sampling_policy(model) if sampling else None, model.num_timesteps)


def _tabular(task: Task, make_env: Callable[[], CampusNavEnv], harness: BudgetHarness, seed: int) -> Trained:
    entry = VARIANTS["DCQN"].entry(task)
    explore_steps = int(entry.hyperparams["exploration_fraction"] * task.max_steps)  # DCQN's schedule, in steps
    agent = TabularQLearning(make_env(), entry.hyperparams["gamma"], explore_steps, seed=seed)
    harness.start()
    agent.learn(harness)
    return Trained(agent.predict_batch, None, agent.num_timesteps)


def _oracle(task: Task, make_env: Callable[[], CampusNavEnv], harness: BudgetHarness, seed: int) -> Trained:
    env = make_env()
    gamma = VARIANTS["DCQN"].entry(task).hyperparams["gamma"]
    q_star = optimal_q_values(
        env.graph, env.goal_nodes[0], gamma, env.goal_reward, env.step_penalty, env.collision_penalty
    )
    return Trained(lambda observations: q_star[env.states_of(observations)].argmax(axis=1), None, 0)


AGENTS: dict[str, Callable[..., Trained]] = {
    "DCQN": _value_based("DCQN"),
    "A2C (target-driven AC)": _actor_critic("A2C"),
    "PPO": _actor_critic("PPO"),
    "DQN": _value_based("DQN"),
    "QR-DQN": _value_based("QR-DQN"),
    "tabular Q": _tabular,
    "oracle": _oracle,
}


# ------------------------------------------------------------------------------------------------------ one run
@dataclass(frozen=True)
class Job:
    """One agent on one goal with one seed."""

    agent: str
    goal: str | int
    seed: int
    budget: float
    eval_every: int
    quick: bool

    def key(self) -> tuple[Any, ...]:
        return (self.agent, goal_label(self.goal), self.seed, self.budget, self.quick)


def record_key(record: dict[str, Any]) -> tuple[Any, ...]:
    """The :meth:`Job.key` of a record's run."""
    return (record["agent"], record["goal"], record["seed"], record["budget"], record["quick"])


def task_for(quick: bool) -> Task:
    task = TASKS["quick"] if quick else TASKS["campus"]
    return replace(task, max_steps=NO_STEP_CAP)


def env_factory(task: Task, goal: str | int) -> Callable[[], CampusNavEnv]:
    """A function that builds a fresh single-goal env (the shipped entry's env settings)."""
    entry = VARIANTS["DCQN"].entry(task)
    kwargs = with_view_build({**entry.env_kwargs, **task.env_kwargs}, progress=False)
    return lambda: CampusNavEnv(goals=goal, **kwargs)


def route_scores(report: RouteReport) -> dict[str, float]:
    return {"success": report.success_rate, "steps": report.mean_steps, "spl": report.spl}


def run_job(job: Job) -> dict[str, Any]:
    """Train one agent on one goal under the budget and evaluate it; the run's record."""
    th.set_num_threads(1)
    task = task_for(job.quick)
    make_env = env_factory(task, job.goal)
    eval_env = make_env()
    harness = BudgetHarness(eval_env, job.budget, job.eval_every)
    trained = AGENTS[job.agent](task, make_env, harness, job.seed)
    train_seconds = 0.0 if job.agent == "oracle" else harness.train_seconds  # before the evaluations below
    routes = evaluate_routes(eval_env, trained.greedy)
    starts = episode_starts(eval_env, job.goal, job.seed)
    test = evaluate_routes(eval_env, trained.greedy, starts=starts, max_steps=TEST_STEP_CAP)
    record: dict[str, Any] = {
        "agent": job.agent,
        "goal": goal_label(job.goal),
        "seed": job.seed,
        "budget": job.budget,
        "quick": job.quick,
        "train_seconds": train_seconds,
        "env_steps": trained.env_steps,
        "route_success": routes.success_rate,
        "route_spl": routes.spl,
        "test": route_scores(test),
        "test_starts": starts.tolist(),
        "solved_at": harness.solved_at(),
        "curve": harness.evaluations,
    }
    if trained.sampling is not None:
        sampled = evaluate_routes(eval_env, trained.sampling, starts=starts, max_steps=TEST_STEP_CAP, stop_loops=False)
        record["test_sampled"] = route_scores(sampled)
    return record


# ------------------------------------------------------------------------------------------------------ the report
def _rows(runs: list[dict[str, Any]]) -> list[tuple[str, str, list[dict[str, Any]]]]:
    """(row name, test key, runs) for each agent, actor-critics twice (greedy and sampled actions)."""
    rows = []
    for agent in AGENTS:
        mine = [run for run in runs if run["agent"] == agent]
        if mine:
            rows.append((agent, "test", mine))
            if agent in ACTOR_CRITICS:
                rows.append((f"{agent}, sampled actions", "test_sampled", mine))
    return rows


def _per_seed(runs: list[dict[str, Any]], value: Callable[[dict[str, Any]], float]) -> list[float]:
    """The mean over goals of ``value``, one figure per seed."""
    seeds = sorted({run["seed"] for run in runs})
    return [statistics.fmean(value(run) for run in runs if run["seed"] == seed) for seed in seeds]


def _mean_spread(values: list[float], digits: int = 2) -> str:
    if len(values) == 1:
        return f"{values[0]:.{digits}f}"
    return f"{statistics.fmean(values):.{digits}f} ± {statistics.stdev(values):.{digits}f}"


def solved_seconds(run: dict[str, Any]) -> float | None:
    """Training seconds to the first route evaluation at the thresholds, the one after training included."""
    if run["solved_at"] is not None:
        return run["solved_at"]["seconds"]
    if run["route_success"] >= SOLVED_SUCCESS and run["route_spl"] >= SOLVED_SPL:
        return run["train_seconds"]
    return None


def summary_lines(runs: list[dict[str, Any]], eval_every: int) -> list[str]:
    goals = sorted({run["goal"] for run in runs})
    seeds = sorted({run["seed"] for run in runs})
    budgets = sorted({run["budget"] for run in runs})
    lines = [
        f"{len(goals)} goals, seeds {seeds}, training budget {', '.join(f'{b:g}' for b in budgets)} s per goal "
        f"(evaluations excluded). Test: {TEST_EPISODES} episodes per goal from the same random starts for every "
        f"agent, capped at {TEST_STEP_CAP} steps (a failure counts {TEST_STEP_CAP}). Figures are means over goals; "
        "with several seeds, mean ± standard deviation over the seeds' means. Routes from every (start, heading) are "
        f"evaluated every {eval_every:,} env steps and after training; time to solved: training seconds at the first "
        f"evaluation with success >= {SOLVED_SUCCESS} and SPL >= {SOLVED_SPL}.",
        "",
        "| agent | env steps in the budget | test success | test mean steps | test SPL | route success "
        f"(every start) | route SPL | goals solved (success {SOLVED_SUCCESS}, SPL {SOLVED_SPL}) | "
        "median time to solved |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, key, mine in _rows(runs):
        solved = [seconds for run in mine if (seconds := solved_seconds(run)) is not None]
        is_oracle = mine[0]["agent"] == "oracle"
        lines.append(
            "| "
            + " | ".join(
                [
                    name,
                    "-" if is_oracle else f"{statistics.fmean(run['env_steps'] for run in mine):,.0f}",
                    _mean_spread(_per_seed(mine, lambda run, k=key: run[k]["success"])),
                    _mean_spread(_per_seed(mine, lambda run, k=key: run[k]["steps"]), 1),
                    _mean_spread(_per_seed(mine, lambda run, k=key: run[k]["spl"])),
                    "-" if key == "test_sampled" else _mean_spread(_per_seed(mine, lambda run: run["route_success"])),
                    "-" if key == "test_sampled" else _mean_spread(_per_seed(mine, lambda run: run["route_spl"])),
                    "-" if is_oracle or key == "test_sampled" else f"{len(solved)}/{len(mine)}",
                    "-" if is_oracle or not solved or key == "test_sampled" else f"{statistics.median(solved):.1f} s",
                ]
            )
            + " |"
        )
    return lines


def step_ratio_lines(runs: list[dict[str, Any]]) -> list[str]:
    """The actor-critic's test steps over DCQN's, next to the paper's 4.5."""
    by_agent = {agent: [run for run in runs if run["agent"] == agent] for agent in ("DCQN", ACTOR_CRITICS[0])}
    if not all(by_agent.values()):
        return []
    dcqn = statistics.fmean(run["test"]["steps"] for run in by_agent["DCQN"])
    lines = ["", "| ratio of test mean steps | here | paper |", "|---|---|---|"]
    for label, key in (("A2C greedy / DCQN", "test"), ("A2C sampled actions / DCQN", "test_sampled")):
        ac = statistics.fmean(run[key]["steps"] for run in by_agent[ACTOR_CRITICS[0]])
        lines.append(f"| {label} | {ac / dcqn:.2f} ({ac:.1f} / {dcqn:.1f} steps) | {PAPER_AC_STEP_RATIO} |")
    return lines


def per_goal_lines(runs: list[dict[str, Any]]) -> list[str]:
    agents = [agent for agent in AGENTS if any(run["agent"] == agent for run in runs)]
    goals = list(dict.fromkeys(run["goal"] for run in runs))
    lines = [
        "",
        "Test mean steps per goal (mean over seeds; the oracle's is the shortest route's length):",
        "",
        "| goal | " + " | ".join(agents) + " |",
        "|---" * (len(agents) + 1) + "|",
    ]
    for goal in goals:
        cells = []
        for agent in agents:
            steps = [run["test"]["steps"] for run in runs if run["agent"] == agent and run["goal"] == goal]
            cells.append(f"{statistics.fmean(steps):.1f}" if steps else "-")
        lines.append(f"| {goal} | " + " | ".join(cells) + " |")
    return lines


def draw(runs: list[dict[str, Any]], path: Path) -> None:
    rows = _rows(runs)
    figure = Figure(figsize=(11, 4.2))
    panels = (("steps", "test mean steps (cap 200)"), ("success", "test success"), ("spl", "test SPL"))
    for index, (metric, title) in enumerate(panels):
        axes = figure.add_subplot(1, 3, index + 1)
        for position, (_, key, mine) in enumerate(rows):
            values = _per_seed(mine, lambda run, k=key, m=metric: run[k][m])
            spread = statistics.stdev(values) if len(values) > 1 else 0.0
            axes.bar(position, statistics.fmean(values), yerr=spread, capsize=3, color=f"C{position % 10}")
        axes.set_xticks(range(len(rows)), [name for name, _, _ in rows], rotation=60, ha="right", fontsize=7)
        axes.set_title(title, fontsize=9)
    figure.suptitle("Equal training budget per goal: mean over goals (error bars: spread over seeds)", fontsize=10)
    figure.tight_layout()
    write_figure(path, figure_image(figure))


# ------------------------------------------------------------------------------------------------------ the script
def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--budget", type=float, default=5.0, help="training seconds per goal (paper: 300)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--goals", type=int, default=N_GOALS, help="how many of the 14 goals")
    parser.add_argument("--agents", nargs="+", default=list(AGENTS), choices=list(AGENTS))
    parser.add_argument("--eval-every", type=int, default=2_000, help="route evaluation every this many env steps")
    parser.add_argument("--quick", action="store_true", help="smoke run: 2 goals, 2 s, cheap pixel features")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "compare.md")
    parser.add_argument("--runs-file", type=Path, default=RESULTS_DIR / "compare_runs.jsonl")
    workers_argument(parser, default=None)
    args = parser.parse_args(argv)
    if args.quick:
        args.goals, args.budget, args.eval_every = min(args.goals, 2), min(args.budget, 2.0), min(args.eval_every, 300)
    return args


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    task = task_for(args.quick)
    goals = campus_goals(env_factory(task, GOALS[0])(), args.goals)
    jobs = [
        Job(agent, goal, seed, args.budget, args.eval_every, args.quick)
        for seed in args.seeds
        for goal in goals
        for agent in args.agents
    ]
    stored = run_missing(
        args.runs_file,
        jobs,
        run_job,
        key=record_key,
        job_key=Job.key,
        workers=args.workers,
        describe=lambda record: (
            f"{record['agent']:<24} {record['goal']:<18} seed {record['seed']}: {record['env_steps']:>7} steps, "
            f"test success {record['test']['success']:.2f}, mean steps {record['test']['steps']:.1f}"
        ),
    )
    done = {record_key(record): record for record in stored.records}
    runs = [done[job.key()] for job in jobs]
    image = args.out.with_suffix(".png")
    draw(runs, image)
    lines = [
        "# Equal-budget comparison on the campus",
        "",
        machine_line(f"runs in {args.workers} worker process(es)"),
        "",
        *summary_lines(runs, args.eval_every),
        *step_ratio_lines(runs),
        *per_goal_lines(runs),
        "",
        f"![test scores per agent]({image.name})",
    ]
    publish(args.out, lines, "compare.py", None if argv is None else list(argv))


if __name__ == "__main__":
    main()
