"""One city run, shared by the scripts that train on cities (``long_routes.py``: each long-route lever alone;
``city_scale.py``: one entry at every size): the rows (an entry and what is changed in it), a job (a row on a map
with a seed and a budget), its env and its run until solved, and how the runs' figures are summarised."""

from __future__ import annotations

import copy
import statistics
import time
from dataclasses import dataclass, field, replace
from typing import Any

from benchmarks.scale_common import buffer_arrays, peak_memory

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


def median_worst(values: list[float], worst_is_max: bool = True, digits: int = 0) -> str:
    """``median (worst)`` of the runs' values; one run: the value."""
    if not values:
        return "-"
    worst = max(values) if worst_is_max else min(values)
    if len(values) == 1:
        return f"{values[0]:,.{digits}f}"
    return f"{statistics.median(values):,.{digits}f} ({worst:,.{digits}f})"
