"""Throughput: DCQN vs SB3 DQN with identical layer sizes, in the same process.

Measures, for each configuration,
- time per gradient step (``model.train`` on a filled replay buffer: sampling, forward, backward, Adam), and
- time per env step of ``learn`` (collection + action selection + training at ``train_freq=4``),
alternating DQN and DCQN repeats so that machine noise hits both alike, and prints the DCQN/DQN ratio of the medians.

Usage::

    python benchmarks/throughput.py                # default configurations, writes benchmarks/results/throughput.md
    python benchmarks/throughput.py --repeats 7 --threads 1
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import DQN
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from benchmarks.report import RESULTS_DIR, command_line, machine_line, markdown_table, table_row, write_results
from sb3_dcqn import DCQN
from sb3_dcqn.fusion import EmbeddingFusionExtractor
from sb3_dcqn.replay import RevisionPrioritizedReplayBuffer


class RandomObservationEnv(gym.Env):
    """A cheap env with random observations from any space, 50-step episodes (the update is what is timed)."""

    def __init__(self, observation_space: spaces.Space, n_actions: int = 4, episode_length: int = 50) -> None:
        self.observation_space = observation_space
        self.action_space = spaces.Discrete(n_actions)
        self.episode_length = episode_length
        self._t = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        self.observation_space.seed(seed)
        self._t = 0
        return self.observation_space.sample(), {}

    def step(self, action: np.int64) -> tuple[Any, float, bool, bool, dict]:
        self._t += 1
        reward = 1.0 if action == 0 else 0.0
        return self.observation_space.sample(), reward, False, self._t >= self.episode_length, {}


# CampusNav's observation with EfficientNet-Lite0 features: 4 views x 1280 for the intersection and the goal
CAMPUSNAV_SPACE = spaces.Dict(
    {
        "views": spaces.Box(-5.0, 5.0, shape=(4 * 1280,), dtype=np.float32),
        "goal_views": spaces.Box(-5.0, 5.0, shape=(4 * 1280,), dtype=np.float32),
        "heading": spaces.Box(0.0, 1.0, shape=(4,), dtype=np.float32),
    }
)
FUSION = dict(
    features_extractor_class=EmbeddingFusionExtractor,
    features_extractor_kwargs=dict(embed_dim=256, features_dim=256),
)


@dataclass(frozen=True)
class Config:
    name: str
    env_id: str  # a registered id, or "campusnav-features" for CAMPUSNAV_SPACE
    net_arch: tuple[int, ...]
    batch_size: int
    policy: str = "MlpPolicy"
    extractor: dict[str, Any] = field(default_factory=dict)  # policy_kwargs given to both (features extractor, ...)
    dcqn_only: dict[str, Any] = field(default_factory=dict)  # DCQN-only policy_kwargs
    dcqn_options: dict[str, Any] = field(default_factory=dict)  # DCQN-only algorithm options (the levers)


# The demo's re-adaptation levers (DQN has none: the row shows what they cost on top of DCQN's step)
LEVERS = dict(replay_buffer_class=RevisionPrioritizedReplayBuffer, blocked_action_target=True)
# Both algorithms with the same (fused) Adam: what the second critic costs when the optimizer is the same
SAME_ADAM = dict(optimizer_kwargs=dict(fused=True))

CONFIGS = (
    Config("CartPole-v1, net [64, 64], batch 64", "CartPole-v1", (64, 64), 64),
    Config("CartPole-v1, net [256, 256], batch 64", "CartPole-v1", (256, 256), 64),
    Config("CartPole-v1, net [256, 256], batch 128", "CartPole-v1", (256, 256), 128),
    Config(
        "CartPole-v1, net [256, 256], batch 64, fused Adam for both", "CartPole-v1", (256, 256), 64, extractor=SAME_ADAM
    ),
    Config(
        "CartPole-v1, net [256, 256], batch 64, DCQN with revision + blocked target + PER",
        "CartPole-v1",
        (256, 256),
        64,
        dcqn_options=LEVERS,
    ),
    Config(
        "CampusNav features, fusion 256 (separate per critic), net [256], batch 64",
        "campusnav-features",
        (256,),
        64,
        "MultiInputPolicy",
        FUSION,
    ),
    Config(
        "CampusNav features, fusion 256 (shared by the critics), net [256], batch 64",
        "campusnav-features",
        (256,),
        64,
        "MultiInputPolicy",
        FUSION,
        dict(share_features_extractor=True),
    ),
)


def make_model(algo: type[OffPolicyAlgorithm], config: Config, seed: int) -> OffPolicyAlgorithm:
    env = RandomObservationEnv(CAMPUSNAV_SPACE) if config.env_id == "campusnav-features" else gym.make(config.env_id)
    policy_kwargs = dict(net_arch=list(config.net_arch), **config.extractor)
    options = {}
    if algo is DCQN:
        policy_kwargs.update(config.dcqn_only)
        options = config.dcqn_options
    return algo(
        config.policy,
        env,
        learning_starts=0,
        batch_size=config.batch_size,
        buffer_size=20_000,
        train_freq=4,
        target_update_interval=1000,
        policy_kwargs=policy_kwargs,
        seed=seed,
        device="cpu",
        **options,
    )


def time_gradient_steps(model: OffPolicyAlgorithm, n_steps: int) -> float:
    """Seconds per gradient step on a buffer already filled by ``learn``."""
    model.train(gradient_steps=5, batch_size=model.batch_size)  # warm-up
    start = time.perf_counter()
    model.train(gradient_steps=n_steps, batch_size=model.batch_size)
    return (time.perf_counter() - start) / n_steps


def time_env_steps(model: OffPolicyAlgorithm, n_steps: int) -> float:
    """Seconds per env step of ``learn`` (collection plus one gradient step every 4 env steps)."""
    start = time.perf_counter()
    model.learn(n_steps, reset_num_timesteps=False)
    return (time.perf_counter() - start) / n_steps


def run(configs: tuple[Config, ...], repeats: int, grad_steps: int, env_steps: int) -> list[dict[str, float | str]]:
    rows = []
    for config in configs:
        models = {"DQN": make_model(DQN, config, seed=0), "DCQN": make_model(DCQN, config, seed=0)}
        for model in models.values():
            model.learn(2_000)  # fill the buffer, warm up allocators
        grad = {name: [] for name in models}
        env = {name: [] for name in models}
        for _ in range(repeats):
            for name, model in models.items():  # alternate so that noise hits both
                grad[name].append(time_gradient_steps(model, grad_steps))
                env[name].append(time_env_steps(model, env_steps))
        row: dict[str, float | str] = {"config": config.name}
        for name in models:
            row[f"{name} grad ms"] = 1e3 * statistics.median(grad[name])
            row[f"{name} env steps/s"] = 1.0 / statistics.median(env[name])
        row["grad ratio"] = row["DCQN grad ms"] / row["DQN grad ms"]
        row["env-step time ratio"] = row["DQN env steps/s"] / row["DCQN env steps/s"]
        rows.append(row)
        print(format_row(row), flush=True)
    return rows


COLUMNS = (
    "config",
    "DQN grad ms",
    "DCQN grad ms",
    "grad ratio",
    "DQN env steps/s",
    "DCQN env steps/s",
    "env-step time ratio",
)


def format_cell(column: str, value: float | str) -> str:
    if isinstance(value, str):
        return value
    return f"{value:.3f}" if "ratio" in column else f"{value:.2f}"


def format_row(row: dict[str, float | str]) -> str:
    return table_row([format_cell(c, row[c]) for c in COLUMNS])


def write_markdown(rows: list[dict[str, float | str]], path: Path, args: argparse.Namespace) -> None:
    lines = [
        "# Throughput: DCQN vs SB3 DQN (same process, same layer sizes)",
        "",
        machine_line(
            f"torch {th.__version__}; medians of {args.repeats} alternating repeats, {args.grad_steps} gradient steps "
            f"and {args.env_steps} env steps each",
            torch_threads=th.get_num_threads(),
        )
        + " Ratios > 1 mean DCQN is slower. Each algorithm runs with its defaults (DCQN's Adam is fused where torch "
        "supports it, SB3 DQN's is not) unless the row says otherwise.",
        "",
        *markdown_table(COLUMNS, [[format_cell(c, row[c]) for c in COLUMNS] for row in rows]),
        "",
        command_line("throughput.py", args.argv),
    ]
    write_results(path, "\n".join(lines))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--grad-steps", type=int, default=300)
    parser.add_argument("--env-steps", type=int, default=2000)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--quick", action="store_true", help="one small configuration, few repeats (smoke run)")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "throughput.md")
    args = parser.parse_args(argv)
    args.argv = argv
    th.set_num_threads(args.threads)
    configs = CONFIGS[:1] if args.quick else CONFIGS
    if args.quick:
        args.repeats, args.grad_steps, args.env_steps = 1, 20, 200
    print(table_row(COLUMNS))
    rows = run(configs, args.repeats, args.grad_steps, args.env_steps)
    write_markdown(rows, args.out, args)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
