"""Quality on classic control: DCQN vs SB3 DQN with the RL Zoo's tuned DQN hyperparameters, several seeds.

Each (algorithm, env, seed) run trains with the env's entry of ``hyperparams/dcqn.yml`` (the zoo's DQN settings, used
unchanged for both algorithms), then evaluates the deterministic policy for 20 episodes. Runs go to a process pool
(one torch thread each); every finished run is appended to a JSON-lines file, so an interrupted benchmark keeps its
results and a rerun skips what is done. The table (mean +- std over seeds of the final evaluation, plus wall time)
is printed and written to ``benchmarks/results/classic_control.md``.

Usage::

    python benchmarks/classic_control.py                          # CartPole-v1 and Acrobot-v1, seeds 0-2, 2 workers
    python benchmarks/classic_control.py --envs CartPole-v1 --seeds 0 1 2 3 4 --workers 2
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.report import RESULTS_DIR, machine_line, publish, run_missing
from benchmarks.workers import workers_argument

HYPERPARAMS = Path(__file__).resolve().parents[1] / "sb3_dcqn" / "hyperparams" / "dcqn.yml"
ALGOS = ("DQN", "DCQN")
# RL Zoo's published DQN scores (rl-baselines3-zoo benchmark table), for reference
ZOO_DQN_REFERENCE = {"CartPole-v1": "500 +- 0 (50k steps)", "Acrobot-v1": "about -75 (100k steps)"}


def run_one(algo_name: str, env_id: str, seed: int, n_eval_episodes: int = 20) -> dict[str, Any]:
    """Train one agent and evaluate it; runs in a worker process."""
    import gymnasium as gym
    import torch as th
    from stable_baselines3 import DQN
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.monitor import Monitor

    from sb3_dcqn import DCQN
    from sb3_dcqn.zoo_entry import load_zoo_entry

    th.set_num_threads(1)
    entry = load_zoo_entry(HYPERPARAMS, env_id)
    n_timesteps, kwargs = entry.n_timesteps, entry.hyperparams
    algo = {"DQN": DQN, "DCQN": DCQN}[algo_name]
    start = time.perf_counter()
    model = algo(env=gym.make(env_id), seed=seed, device="cpu", **kwargs)
    model.learn(n_timesteps)
    train_seconds = time.perf_counter() - start
    eval_env = Monitor(gym.make(env_id))
    eval_env.reset(seed=10_000 + seed)
    mean_reward, std_reward = evaluate_policy(model, eval_env, n_eval_episodes=n_eval_episodes, deterministic=True)
    return {
        "algo": algo_name,
        "env": env_id,
        "seed": seed,
        "n_timesteps": n_timesteps,
        "mean_reward": float(mean_reward),
        "std_reward": float(std_reward),
        "train_seconds": train_seconds,
    }


def run_job(job: tuple[str, str, int]) -> dict[str, Any]:
    """:func:`run_one` of an ``(algorithm, env, seed)`` job."""
    return run_one(*job)


def summarise(results: list[dict[str, Any]], envs: list[str]) -> list[str]:
    lines = [
        "| env | algo | seeds | final eval reward (mean +- std over seeds) | train time per run (s) "
        "| zoo DQN reference |",
        "|---|---|---|---|---|---|",
    ]
    for env_id in envs:
        for algo in ALGOS:
            runs = [r for r in results if r["env"] == env_id and r["algo"] == algo]
            if not runs:
                continue
            rewards = np.array([r["mean_reward"] for r in runs])
            seconds = np.array([r["train_seconds"] for r in runs])
            lines.append(
                f"| {env_id} | {algo} | {len(runs)} | {rewards.mean():.1f} +- {rewards.std():.1f} "
                f"(per seed: {', '.join(f'{v:.0f}' for v in rewards)}) | {seconds.mean():.0f} | "
                f"{ZOO_DQN_REFERENCE.get(env_id, '')} |"
            )
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=["CartPole-v1", "Acrobot-v1"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--algos", nargs="+", default=list(ALGOS), choices=ALGOS)
    workers_argument(parser, default=2)
    parser.add_argument("--runs-file", type=Path, default=RESULTS_DIR / "classic_control_runs.jsonl")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "classic_control.md")
    args = parser.parse_args(argv)

    jobs = [(algo, env_id, seed) for env_id in args.envs for seed in args.seeds for algo in args.algos]
    runs = run_missing(
        args.runs_file,
        jobs,
        run_job,
        key=lambda r: (r["algo"], r["env"], r["seed"]),
        workers=args.workers,
        describe=lambda r: (
            f"{r['algo']:>4} {r['env']:<12} seed {r['seed']}: {r['mean_reward']:8.1f} in {r['train_seconds']:.0f} s"
        ),
    )

    lines = [
        "# Classic control: DCQN vs DQN with the RL Zoo's DQN hyperparameters",
        "",
        machine_line(f"{args.workers} runs in parallel", torch_threads="1 torch thread per run")
        + " Final evaluation: 20 deterministic episodes after training.",
        "Hyperparameters: `hyperparams/dcqn.yml` (identical to rl_zoo3's `dqn.yml` entries) for both algorithms.",
        "",
        *summarise(runs.records, args.envs),
    ]
    publish(args.out, lines, "classic_control.py", argv)


if __name__ == "__main__":
    main()
