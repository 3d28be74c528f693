"""Scale, training: DCQN with the shipped ``CampusNav-v0`` settings until the map is solved, per size.

Until success >= 0.99 and SPL >= 0.98 from every (start, heading)
(``sb3_dcqn.campusnav.experiments.train_until_solved``; time: training seconds, evaluations excluded) or the
``--budget``; env step and reset costs, evaluation time, peak RSS, replay-buffer bytes, a profile of one route
evaluation. Features: those of the size's full EfficientNet build, else
the pixel build. Run by ``scale.py`` (stage ``train``); alone::

    python benchmarks/scale_training.py --sizes 101 --budget 60 --runs-file /tmp/train.jsonl --out /tmp/train.md
"""

from __future__ import annotations

import cProfile
import pstats
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.report import markdown_table
from benchmarks.scale_common import (
    GOAL,
    MB,
    VIEW_DIM,
    Plan,
    buffer_arrays,
    env_kwargs_for,
    make_graph,
    peak_memory,
    rss_mb,
    seconds_per_call,
)

STAGE = "train"


def default_budget(n_nodes: int) -> float:
    """Training seconds per size: DCQN solved 500 nodes in a median 127 s (learning_speed.md)."""
    return 60.0 if n_nodes <= 200 else 420.0 if n_nodes <= 2_000 else 150.0


def default_eval_freq(n_nodes: int) -> int:
    """
    Env steps between route evaluations: one evaluation runs the greedy policy from all 4N (start, heading) pairs, so
    its cost grows with the map (measured: about 0.3 s at 1,000 nodes, several seconds at 10,000); sparser
    evaluations keep it a minor part of the wall time (at the price of a coarser time to threshold).
    """
    return 1_000 if n_nodes <= 200 else 5_000 if n_nodes <= 2_000 else 20_000


def top_functions(profile: cProfile.Profile, count: int = 6) -> list[dict[str, Any]]:
    """The functions with the most own time in a profile, with their share of the total."""
    stats = pstats.Stats(profile)
    total = stats.total_tt or 1.0
    rows = []
    for (filename, line, name), (_, calls, own, cumulative, _) in stats.stats.items():  # type: ignore[attr-defined]
        where = name if filename == "~" else f"{Path(filename).name}:{line} {name}"
        rows.append({"function": where, "calls": calls, "own_share": own / total, "cumulative": cumulative})
    return sorted(rows, key=lambda row: -row["own_share"])[:count]


def measure_training(n_nodes: int, plan: Plan) -> dict[str, Any]:
    """
    DCQN as shipped until the map is solved (or the budget is spent): time, steps, memory, evaluation cost.

    :param n_nodes: Intersections of the generated map
    :param plan: The run (budget, evaluation frequency and step cap of this size)
    :return: the stage's record for this size
    """
    from benchmarks.campusnav_runs import TASKS, VARIANTS
    from campusnav_env.env import CampusNavEnv
    from campusnav_env.features.view_build import with_view_build
    from campusnav_env.route_evaluation import evaluate_routes
    from sb3_dcqn.campusnav.experiments import train_until_solved

    record: dict[str, Any] = {"stage": STAGE, "size": n_nodes, "import_rss_mb": rss_mb()}
    budget, eval_freq, max_steps = plan.budgets[n_nodes], plan.eval_freq[n_nodes], plan.max_steps[n_nodes]
    task = replace(TASKS["campus"], name=f"scale{n_nodes}", n_nodes=n_nodes, env_id=None, max_steps=max_steps)
    variant = VARIANTS["DCQN"]
    entry = variant.entry(task)
    encoder = plan.train_encoder(n_nodes)
    graph = make_graph(n_nodes, plan.extent)
    with peak_memory() as peak:
        begin = time.perf_counter()
        env_kwargs = with_view_build(
            {**entry.env_kwargs, **env_kwargs_for(encoder)}, cache_dir=plan.cache_dir, progress=False
        )
        env = CampusNavEnv(world=graph, goals=GOAL, **env_kwargs)
        record["env_seconds"] = time.perf_counter() - begin
    settings = env_kwargs["view_build"].render_settings
    record |= {"env_peak_mb": peak.peak_mb, "encoder": encoder, "view": f"{settings.width}x{settings.height}"}

    # Env step and reset costs at this size (random actions)
    rng = np.random.default_rng(plan.seed)
    env.reset(seed=plan.seed)
    begin = time.perf_counter()
    for _ in range(plan.env_steps):
        _, _, terminated, truncated, _ = env.step(int(rng.integers(4)))
        if terminated or truncated:
            env.reset()
    record["env_step_us"] = 1e6 * (time.perf_counter() - begin) / plan.env_steps
    record["reset_us"] = 1e6 * seconds_per_call(env.reset, 200)

    model = variant.make_model(env, entry, plan.seed)
    with peak_memory() as peak:
        result = train_until_solved(model, max_steps, budget, eval_freq)
    last, solved = result.evaluations[-1], result.solved_at
    at = solved or last
    buffer = model.replay_buffer
    record |= {
        "solved": solved is not None,
        "seconds": at.train_seconds,
        "steps": at.step,
        "episodes": at.episode,
        "final_steps": last.step,
        "final_train_seconds": last.train_seconds,
        "final_success": last.success_rate,
        "final_spl": last.spl,
        "budget_seconds": budget,
        "eval_freq": eval_freq,
        "max_steps": max_steps,
        "evaluations": len(result.evaluations),
        "evaluation_seconds": result.evaluation_seconds,
        "routes": len(last.report.routes),
        "wall_seconds": result.wall_seconds,
        "train_peak_mb": peak.peak_mb,
        "buffer_class": type(buffer).__name__,
        "buffer_allocated_bytes": sum(buffer_arrays(buffer).values()),
        "buffer_transitions": int(buffer.buffer_size if buffer.full else buffer.pos),
        "buffer_size": int(buffer.buffer_size),
        "curve": result.curve(),
    }

    # Where one route evaluation's time goes (the final policy)
    profile = cProfile.Profile()
    with peak_memory() as peak:
        begin = time.perf_counter()
        report = profile.runcall(
            evaluate_routes, env, lambda observations: model.predict(observations, deterministic=True)[0]
        )
        record["profiled_evaluation_seconds"] = time.perf_counter() - begin
    record["evaluation_extra_mb"] = peak.extra_mb  # all 4N starts go through the policy as one batch
    record["profiled_evaluation_mean_steps"] = report.mean_steps
    record["evaluation_profile"] = top_functions(profile)
    return record


def train_ms_per_step(run: dict[str, Any]) -> float:
    """Training milliseconds per env step over the whole run."""
    return 1e3 * run["final_train_seconds"] / max(run["final_steps"], 1)


def train_table(trains: dict[int, dict[str, Any]]) -> list[str]:
    """Time to the threshold and memory during training, per size."""
    header = [
        "intersections",
        "features",
        "budget (s)",
        "solved",
        "training time to threshold (s)",
        "env steps",
        "episodes",
        "final success / SPL",
        "training ms per env step",
        "evaluations (every N steps)",
        "s per evaluation (routes)",
        "wall (s)",
        "peak RSS: env / training (MB)",
        "replay buffer: allocated / used (MB)",
    ]
    rows = []
    for size in sorted(trains):
        run = trains[size]
        time_cell = f"{run['seconds']:.0f}" if run["solved"] else f"not reached in {run['final_train_seconds']:.0f} s"
        used = run["buffer_allocated_bytes"] * run["buffer_transitions"] / run["buffer_size"]
        rows.append(
            [
                f"{size:,}",
                f"{run['encoder']}, {run['view']}, view_dim {VIEW_DIM}",
                f"{run['budget_seconds']:.0f}",
                "yes" if run["solved"] else "no",
                time_cell,
                f"{run['steps']:,}",
                f"{run['episodes']:,}",
                f"{run['final_success']:.3f} / {run['final_spl']:.3f}",
                f"{train_ms_per_step(run):.2f}",
                f"{run['evaluations']} (every {run['eval_freq']:,})",
                f"{run['evaluation_seconds'] / max(run['evaluations'], 1):.2f} ({run['routes']:,})",
                f"{run['wall_seconds']:.0f}",
                f"{run['env_peak_mb']:,.0f} / {run['train_peak_mb']:,.0f}",
                f"{run['buffer_allocated_bytes'] / MB:,.0f} / {used / MB:,.0f}",
            ]
        )
    return markdown_table(header, rows)


def training_section(trains: dict[int, dict[str, Any]]) -> list[str]:
    """The results section: what counts as solved, and the table."""
    from sb3_dcqn.campusnav.solved import SOLVED_SPL, SOLVED_SUCCESS

    return [
        "## Time to the threshold (DCQN, shipped CampusNav-v0 settings)",
        "",
        f"Success >= {SOLVED_SUCCESS} and SPL >= {SOLVED_SPL} from every (start, heading), evaluated every N "
        "env steps inside one `learn()` call (`sb3_dcqn.campusnav.experiments.train_until_solved`); time: training "
        "seconds, evaluations excluded; a run "
        "that spends its budget is reported with its last evaluation. Replay buffer: the arrays SB3 reserves "
        "(`np.zeros`, touched as they fill) and the share filled.",
        "",
        *train_table(trains),
    ]
