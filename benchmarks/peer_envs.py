"""The route memory on the envs a user would try it on first: DQN and DCQN, memory on and off, the same settings.

Every (env, algorithm, memory, seed) run trains for the env's budget with the env's settings (the same for the memory
on and off: only ``route_memory`` differs), then plays 100 greedy episodes from seeded starts with ``episode_start``
and the model's state (as SB3's ``evaluate_policy``). Worlds: FrozenLake 8x8 deterministic and slippery (a stochastic
world: the memory plans on outcome counts), CliffWalking, Taxi (deterministic grid worlds the memory remembers
exactly), CartPole (continuous observations that never repeat: the memory steps aside) with the RL Zoo's DQN settings
(``hyperparams/dcqn.yml``), and MiniGrid's Empty 8x8 and DoorKey 5x5 seen whole (``FullyObsWrapper``; the ``bench``
extra installs ``minigrid``). Besides the return, each memory run records whether the memory stepped aside for good,
stood aside at the end, its prediction accuracy and its stochastic moves. Runs go to worker processes (one torch
thread each) and to a JSON-lines file, so an interrupted benchmark keeps its results and a rerun skips what is done.
The table (median and worst over seeds, per seed) is printed and written to ``benchmarks/results/peer_envs.md``.

Usage::

    python benchmarks/peer_envs.py                                   # every env, DQN and DCQN, seeds 11 12 13
    python benchmarks/peer_envs.py --envs FrozenLake-slippery --algos DQN --seeds 11 12 13 --workers 2
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.report import RESULTS_DIR, machine_line, markdown_table, publish, run_missing
from benchmarks.workers import workers_argument

HYPERPARAMS = Path(__file__).resolve().parents[1] / "sb3_dcqn" / "hyperparams" / "dcqn.yml"
ALGOS = ("DQN", "DCQN")
EVAL_EPISODES = 100
# The tabular worlds' settings (the same for every algorithm, memory on and off): a small net, exploration over the
# first 30% of the budget
GRID_SETTINGS: dict[str, Any] = {
    "policy": "MlpPolicy",
    "learning_starts": 1000,
    "exploration_fraction": 0.3,
    "exploration_final_eps": 0.05,
    "target_update_interval": 500,
    "train_freq": 4,
    "batch_size": 64,
    "gamma": 0.99,
    "learning_rate": 1e-3,
    "policy_kwargs": {"net_arch": [64, 64]},
}


@dataclass(frozen=True)
class PeerEnv:
    """One env of the benchmark: how to make it, its budget, its settings, and what a success pays."""

    gym_id: str
    n_timesteps: int
    world: str  # deterministic, stochastic, continuous
    make_kwargs: dict[str, Any] = field(default_factory=dict)
    # The memory's success_reward: these envs give no is_success; a terminated transition paying more than this
    # reached the goal (None: no goal, as CartPole's falls)
    success_reward: float | None = None
    zoo_entry: bool = False  # the settings are the env's entry of hyperparams/dcqn.yml (else GRID_SETTINGS)
    package: str | None = None  # the package that registers the env (imported first), where Gymnasium does not
    wrappers: tuple[str, ...] = ()  # class paths of the wrappers applied, in order

    def make(self) -> Any:
        import importlib

        import gymnasium as gym

        if self.package is not None:
            try:
                importlib.import_module(self.package)
            except ImportError as error:
                raise SystemExit(f"{self.gym_id} needs {self.package}: pip install -e '.[bench]' ({error})") from None
        env = gym.make(self.gym_id, **self.make_kwargs)
        for path in self.wrappers:
            module, _, name = path.rpartition(".")
            env = getattr(importlib.import_module(module), name)(env)
        return env


MINIGRID_WHOLE = ("minigrid.wrappers.FullyObsWrapper", "minigrid.wrappers.ImgObsWrapper")
ICE, SLIPPERY = {"map_name": "8x8", "is_slippery": False}, {"map_name": "8x8", "is_slippery": True}
ENVS = {
    "FrozenLake-deterministic": PeerEnv("FrozenLake-v1", 50_000, "deterministic", ICE, 0.0),
    "FrozenLake-slippery": PeerEnv("FrozenLake-v1", 50_000, "stochastic", SLIPPERY, 0.0),
    # CliffWalking ends only at its goal (-1 there; the cliff, -100, sends the agent back without ending): its
    # episodes are cut at 200 steps, as FrozenLake's (Gymnasium registers it with no limit)
    "CliffWalking": PeerEnv("CliffWalking-v1", 20_000, "deterministic", {"max_episode_steps": 200}, -50.0),
    # Taxi pays +20 for the passenger dropped where asked, the one end of an episode short of the time limit
    "Taxi": PeerEnv("Taxi-v4", 50_000, "deterministic", {}, 0.0),
    "CartPole": PeerEnv("CartPole-v1", 50_000, "continuous", {}, None, zoo_entry=True),
    # MiniGrid seen whole (the grid, the agent's cell and heading, the key and the door: every state one picture),
    # paying 1 - 0.9 * steps / max_steps at the goal, nothing elsewhere; seven actions, three of them moves
    "MiniGrid-Empty": PeerEnv("MiniGrid-Empty-8x8-v0", 30_000, "deterministic", {}, 0.0, package="minigrid",
                              wrappers=MINIGRID_WHOLE),
    "MiniGrid-DoorKey": PeerEnv("MiniGrid-DoorKey-5x5-v0", 50_000, "deterministic", {}, 0.0, package="minigrid",
                                wrappers=MINIGRID_WHOLE),
}  # fmt: skip


def settings_for(peer: PeerEnv, env_id: str) -> tuple[int, dict[str, Any]]:
    """The budget and the algorithm's settings of one env (the same for the memory on and off)."""
    if not peer.zoo_entry:
        return peer.n_timesteps, dict(GRID_SETTINGS)
    from sb3_dcqn.zoo_entry import load_zoo_entry

    entry = load_zoo_entry(HYPERPARAMS, peer.gym_id)
    return entry.n_timesteps, dict(entry.hyperparams)


def greedy_returns(model: Any, env: Any, episodes: int, seed: int) -> np.ndarray:
    """The returns of ``episodes`` greedy episodes from seeded starts, each with ``episode_start`` and the model's
    state passed back (as SB3's ``evaluate_policy`` does)."""
    returns = np.zeros(episodes)
    for episode in range(episodes):
        observation, _ = env.reset(seed=seed + episode)
        state, start, done = None, True, False
        while not done:
            action, state = model.predict(observation, state=state, episode_start=np.array([start]), deterministic=True)
            observation, reward, terminated, truncated, _ = env.step(int(np.asarray(action).reshape(-1)[0]))
            returns[episode] += float(reward)
            start, done = False, terminated or truncated
    return returns


def exact_success(model: Any, env: Any) -> float:
    """
    FrozenLake's greedy success without sampling noise: the chance that the model's greedy action at every state (one
    batch, no episode's history) reaches the goal from the start within the time limit, under the env's own model
    (``env.unwrapped.P``). A hundred episodes judge a success rate within about 0.05; this, exactly.
    """
    table, limit = env.unwrapped.P, env.spec.max_episode_steps
    policy = np.asarray(model.predict(np.arange(len(table)), deterministic=True)[0]).reshape(-1)
    chance = np.zeros(len(table))  # of reaching the goal within the steps left
    for _ in range(limit):
        chance = np.array(
            [sum(p * (r if end else chance[s]) for p, s, r, end in table[state][int(policy[state])]) for state in table]
        )
    return float(chance[0])


def run_one(env_name: str, algo_name: str, memory: bool, seed: int) -> dict[str, Any]:
    """Train one agent and play its greedy episodes; runs in a worker process."""
    import warnings

    from stable_baselines3 import DQN

    from sb3_dcqn import DCQN
    from sb3_dcqn.route_memory.layer import with_route_memory

    peer = ENVS[env_name]
    n_timesteps, settings = settings_for(peer, env_name)
    algorithm = {"DQN": DQN, "DCQN": DCQN}[algo_name]
    if memory:
        algorithm = with_route_memory(algorithm)
        route_memory = {} if peer.success_reward is None else {"success_reward": peer.success_reward}
        settings["route_memory"] = route_memory
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the memory's one warning is recorded below instead
        model = algorithm(env=peer.make(), seed=seed, device="cpu", **settings)
        model.learn(n_timesteps)
    seconds = time.perf_counter() - start
    returns = greedy_returns(model, peer.make(), EVAL_EPISODES, 10_000 + 100 * seed)
    record: dict[str, Any] = {
        "env": env_name,
        "algo": algo_name,
        "memory": memory,
        "seed": seed,
        "n_timesteps": n_timesteps,
        "mean_return": float(returns.mean()),
        "train_seconds": seconds,
    }
    if peer.gym_id == "FrozenLake-v1":
        record["exact_success"] = exact_success(model, peer.make())
    if memory:
        statistics = model.memory.statistics()
        record.update(
            stepped_aside=bool(statistics["stepped_aside"]),
            standing_aside=bool(statistics["standing_aside"]),
            prediction_accuracy=statistics["prediction_accuracy"],
            stochastic_moves=int(statistics["stochastic_moves"]),
            states=int(statistics["states"]),
        )
    return record


def run_job(job: tuple[str, str, bool, int]) -> dict[str, Any]:
    """:func:`run_one` of an ``(env, algorithm, memory, seed)`` job."""
    return run_one(*job)


def _memory_words(runs: list[dict[str, Any]]) -> str:
    """What the memory did over a row's runs: stepped aside for good, stood aside at the end, its accuracy."""
    if not runs or "stepped_aside" not in runs[0]:
        return "-"
    aside = sum(r["stepped_aside"] for r in runs)
    standing = sum(r["standing_aside"] for r in runs)
    accuracies = [r["prediction_accuracy"] for r in runs if r["prediction_accuracy"] == r["prediction_accuracy"]]
    words = [f"stepped aside {aside}/{len(runs)}", f"standing aside at the end {standing}/{len(runs)}"]
    if accuracies:
        words.append(f"predictions {min(accuracies):.2f}-{max(accuracies):.2f}")
    stochastic = [r["stochastic_moves"] for r in runs]
    if any(stochastic):
        words.append(f"stochastic moves {min(stochastic)}-{max(stochastic)}")
    return ", ".join(words)


def _spread(values: list[float]) -> str:
    """``median (worst): per seed`` (``-``: none)."""
    if not values:
        return "-"
    return f"{np.median(values):.3g} ({min(values):.3g}): {', '.join(f'{v:.3g}' for v in values)}"


def _runs_of(records: list[dict[str, Any]], env_name: str, algo: str, memory: bool) -> list[dict[str, Any]]:
    """One table cell's runs (an env, an algorithm, the memory off or on), in seed order."""
    runs = (r for r in records if (r["env"], r["algo"], r["memory"]) == (env_name, algo, memory))
    return sorted(runs, key=lambda r: r["seed"])


def _seeds_of(records: list[dict[str, Any]], env_name: str, algo: str) -> list[int]:
    return sorted({r["seed"] for r in records if (r["env"], r["algo"]) == (env_name, algo)})


def exact_table(records: list[dict[str, Any]], envs: list[str], algos: list[str]) -> list[str]:
    """FrozenLake's exact greedy success (:func:`exact_success`), memory off and on, where the runs measured it."""
    rows = []
    for env_name in envs:
        for algo in algos:
            cells = [
                _spread([r["exact_success"] for r in _runs_of(records, env_name, algo, memory) if "exact_success" in r])
                for memory in (False, True)
            ]
            if cells != ["-", "-"]:
                rows.append([env_name, algo, " ".join(map(str, _seeds_of(records, env_name, algo))), *cells])
    header = ["env", "algo", "seeds", "memory off: median (worst): per seed", "memory on"]
    return markdown_table(header, rows) if rows else []


def summarise(records: list[dict[str, Any]], envs: list[str], algos: list[str]) -> list[str]:
    """The table: per env and algorithm, the memory off and on side by side (median, worst, per seed)."""
    rows = []
    for env_name in envs:
        for algo in algos:
            cells = []
            for memory in (False, True):
                runs = _runs_of(records, env_name, algo, memory)
                cells.append(_spread([r["mean_return"] for r in runs]))
                if memory:
                    cells.append(_memory_words(runs))
            seeds = _seeds_of(records, env_name, algo)
            if seeds:
                rows.append([env_name, ENVS[env_name].world, algo, " ".join(map(str, seeds)), *cells])
    header = ["env", "world", "algo", "seeds", "memory off: median (worst): per seed", "memory on", "the memory"]
    return markdown_table(header, rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=list(ENVS), choices=list(ENVS))
    parser.add_argument("--algos", nargs="+", default=list(ALGOS), choices=ALGOS)
    parser.add_argument("--seeds", nargs="+", type=int, default=[11, 12, 13])
    workers_argument(parser, default=2)
    parser.add_argument("--runs-file", type=Path, default=RESULTS_DIR / "peer_envs_runs.jsonl")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "peer_envs.md")
    args = parser.parse_args(argv)

    jobs = [
        (env_name, algo, memory, seed)
        for env_name in args.envs
        for algo in args.algos
        for seed in args.seeds
        for memory in (False, True)
    ]
    runs = run_missing(
        args.runs_file,
        jobs,
        run_job,
        key=lambda r: (r["env"], r["algo"], r["memory"], r["seed"]),
        workers=args.workers,
        describe=lambda r: (
            f"{r['env']:<24} {r['algo']:>4} memory {'on ' if r['memory'] else 'off'} seed {r['seed']}: "
            f"{r['mean_return']:8.3f} in {r['train_seconds']:.0f} s"
        ),
    )
    lines = [
        "# The route memory on peer envs: DQN and DCQN, memory on and off, the same settings",
        "",
        machine_line(f"{args.workers} runs in parallel", torch_threads="1 torch thread per run")
        + f" Return: the mean of {EVAL_EPISODES} greedy episodes from seeded starts after training.",
        "Settings: FrozenLake, CliffWalking and Taxi `benchmarks/peer_envs.py`'s GRID_SETTINGS; CartPole its "
        "`hyperparams/dcqn.yml` entry (the zoo's DQN settings); budgets: FrozenLake and Taxi 50k env steps, "
        "CliffWalking 20k, CartPole 50k. FrozenLake's return is its success rate.",
        "",
        *summarise(runs.records, args.envs, args.algos),
    ]
    exact = exact_table(runs.records, args.envs, args.algos)
    if exact:
        lines += [
            "",
            "FrozenLake's greedy success, exact: the chance that the greedy action of every state reaches the goal "
            "from the start within the 200-step limit, under the env's own transition model (no sampling noise; the "
            "episodes above judge it within about 0.05).",
            "",
            *exact,
        ]
    publish(args.out, lines, "peer_envs.py", argv)


if __name__ == "__main__":
    main()
