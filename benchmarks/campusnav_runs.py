"""What the CampusNav benchmarks share: the tasks, the agents compared, and training until the map is solved.

A *task* is a map and its goals (the built-in campus with one or four goals, or a generated campus of a few hundred
intersections) with the shipped YAML entry that trains on it. A *variant* is an agent: DCQN as shipped, DCQN without
the heading-relative critics (the network SB3's DQN can have too), SB3's DQN with the same settings, and DCQN with
the paper's settings. :func:`train_until_solved` trains one agent inside one ``learn()`` call, evaluating the greedy
routes from every (start, heading) every ``eval_freq`` steps, and stops at the first evaluation at the thresholds or
when the training-time budget is spent (evaluation time excluded).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
from stable_baselines3 import DQN
from stable_baselines3.common.base_class import BaseAlgorithm

import campusnav_env  # noqa: F401  (registers the CampusNav ids)
from campusnav_env.env import CampusNavEnv
from campusnav_env.maps.campus import generate_campus
from campusnav_env.rendering.street_view import RenderSettings
from sb3_dcqn import DCQN

# Training until solved lives in the glue; re-exported for the scripts that import it from here (scale.py)
from sb3_dcqn.campusnav.experiments import SolveResult as SolveResult
from sb3_dcqn.campusnav.experiments import TrainingBudget as TrainingBudget
from sb3_dcqn.campusnav.experiments import train_until_solved as train_until_solved
from sb3_dcqn.zoo import ZooEntry, default_hyperparams_path, load_zoo_entry, paper_hyperparams_path

# The threshold for a solved map
SUCCESS_THRESHOLD = 0.99
SPL_THRESHOLD = 0.98


@dataclass(frozen=True)
class Task:
    """
    A map, its goals and the shipped YAML entry that trains on it.

    :param name: Short name (command line, results)
    :param description: What the task is, for tables
    :param entry_env_id: The YAML entry to train with
    :param env_id: A registered env id, or ``None`` for a generated campus of ``n_nodes`` intersections
    :param n_nodes: Intersections of the generated campus
    :param max_steps: Step cap (a run that reaches it unsolved is reported as a miss)
    :param budget_seconds: Training-time cap (evaluation excluded)
    :param goal_seconds: The issue's goal for the time to a solved map
    :param eval_freq: Route evaluation every this many env steps
    :param env_kwargs: Extra env arguments (e.g. a cheap encoder for smoke runs)
    """

    name: str
    description: str
    entry_env_id: str
    env_id: str | None = None
    n_nodes: int = 101
    max_steps: int = 100_000
    budget_seconds: float = 120.0
    goal_seconds: float = 60.0
    eval_freq: int = 1_000
    env_kwargs: dict[str, Any] = field(default_factory=dict)

    def make_env(self, entry: ZooEntry, **env_kwargs: Any) -> gym.Env:
        """The training env (the evaluation runs on the same env, between episodes' steps)."""
        kwargs = {**entry.env_kwargs, "progress": False, **self.env_kwargs, **env_kwargs}
        if self.env_id is not None:
            return gym.make(self.env_id, **kwargs)
        # A generated campus keeps the default campus's landmark names; its goal is Dreese Lab
        return CampusNavEnv(world=generate_campus(self.n_nodes, seed=0), goals="Dreese Lab", **kwargs)


TASKS = {
    task.name: task
    for task in (
        Task("campus", "CampusNav-v0 (101 nodes, 1 goal)", "CampusNav-v0", "CampusNav-v0", 101, 60_000, 120, 60),
        Task("multi", "CampusNavMulti-v0 (101 nodes, 4 goals)", "CampusNavMulti-v0", "CampusNavMulti-v0", 101,
             max_steps=240_000, budget_seconds=600, goal_seconds=300, eval_freq=2_000),
        Task("campus200", "generated campus, 200 nodes, 1 goal", "CampusNav-v0", None, 200,
             max_steps=200_000, budget_seconds=450, goal_seconds=300, eval_freq=2_000),
        Task("campus500", "generated campus, 500 nodes, 1 goal", "CampusNav-v0", None, 500,
             max_steps=600_000, budget_seconds=900, goal_seconds=900, eval_freq=5_000),
        # A smoke run: small street views, a cheap pixel encoder, a few hundred steps (tests and --quick)
        Task("quick", "smoke run (CampusNav-v0, 64x48 pixel features)", "CampusNav-v0", "CampusNav-v0", 101,
             max_steps=600, budget_seconds=30, goal_seconds=30, eval_freq=300,
             env_kwargs={"encoder": "pixels", "render_settings": RenderSettings(width=64, height=48)}),
    )
}  # fmt: skip


@dataclass(frozen=True)
class Variant:
    """
    An agent: an algorithm, the hyperparameter file it reads, and changes to its entry.

    :param name: Name in tables
    :param algo: ``"DCQN"`` or ``"DQN"``
    :param paper: Read ``dcqn_paper.yml`` instead of ``dcqn.yml``
    :param drop_policy_kwargs: ``policy_kwargs`` keys removed from the entry (what the other policy does not have)
    :param overrides: Algorithm keyword arguments replaced in the entry
    :param policy_overrides: ``policy_kwargs`` entries replaced in the entry
    :param env_overrides: ``env_kwargs`` entries replaced in the entry (``None`` values remove the key)
    """

    name: str
    algo: str = "DCQN"
    paper: bool = False
    drop_policy_kwargs: tuple[str, ...] = ()
    overrides: dict[str, Any] = field(default_factory=dict)
    policy_overrides: dict[str, Any] = field(default_factory=dict)
    env_overrides: dict[str, Any] = field(default_factory=dict)

    def entry(self, task: Task) -> ZooEntry:
        path = paper_hyperparams_path() if self.paper else default_hyperparams_path()
        entry = load_zoo_entry(path, task.entry_env_id)
        hyperparams = copy.deepcopy(entry.hyperparams)
        for key in self.drop_policy_kwargs:
            hyperparams.get("policy_kwargs", {}).pop(key, None)
        hyperparams.update(self.overrides)
        if self.policy_overrides:
            hyperparams["policy_kwargs"] = {**hyperparams.get("policy_kwargs", {}), **self.policy_overrides}
        env_kwargs = {**entry.env_kwargs, **self.env_overrides}
        env_kwargs = {key: value for key, value in env_kwargs.items() if value is not None}
        # Exploration is set in steps by the YAML's n_timesteps; keep that many steps whatever the step cap
        explore_steps = hyperparams.get("exploration_fraction", 0.1) * entry.n_timesteps
        hyperparams["exploration_fraction"] = min(explore_steps / task.max_steps, 1.0)
        return ZooEntry(task.max_steps, hyperparams, env_kwargs, entry.n_envs)

    def make_model(self, env: gym.Env, entry: ZooEntry, seed: int, **kwargs: Any) -> BaseAlgorithm:
        algo = {"DCQN": DCQN, "DQN": DQN}[self.algo]
        return algo(env=env, seed=seed, device="cpu", **{**entry.hyperparams, **kwargs})


VARIANTS = {
    variant.name: variant
    for variant in (
        Variant("DCQN"),
        # The critics read the heading like any other input: the network SB3's DQN can have too
        Variant("DCQN, no heading_key", drop_policy_kwargs=("heading_key",)),
        Variant("DQN", algo="DQN", drop_policy_kwargs=("heading_key", "share_features_extractor")),
        Variant("DCQN, paper settings", paper=True),
        # The CampusNav-v0 entry before the learning-speed work: full 1280-d features, width 256, lr 1e-4
        Variant(
            "DCQN, previous settings",
            drop_policy_kwargs=("heading_key",),
            overrides={"learning_rate": 1e-4},
            policy_overrides={"features_extractor_kwargs": {"embed_dim": 256, "features_dim": 256}, "net_arch": [256]},
            env_overrides={"view_dim": None},
        ),
    )
}


# ------------------------------------------------------------------------------------------------ closure experiments
@dataclass(frozen=True)
class Lever:
    """
    A re-adaptation lever of DCQN (``benchmarks/closures_*.py``): algorithm options and env options on top of the
    shipped entry.

    :param name: Name in tables
    :param overrides: DCQN keyword arguments added to (or replacing) the entry's
    :param env_kwargs: Env keyword arguments added to the entry's (e.g. ``visible_closures=True``)
    """

    name: str
    overrides: dict[str, Any] = field(default_factory=dict)
    env_kwargs: dict[str, Any] = field(default_factory=dict)

    def entry(self, task: Task) -> ZooEntry:
        """The shipped DCQN entry for ``task`` with this lever's options."""
        entry = Variant(self.name, overrides=self.overrides).entry(task)
        return ZooEntry(entry.n_timesteps, entry.hyperparams, {**entry.env_kwargs, **self.env_kwargs}, entry.n_envs)


_ALL_LEVERS = {
    "experience_revision": True,
    "prioritized_replay": True,
    "adaptation_boost": {"trigger": "revision"},
}
LEVERS = {
    "baseline": Lever("baseline (DCQN as shipped)"),
    "revision": Lever("experience revision", {"experience_revision": True}),
    "per": Lever("prioritised replay", {"prioritized_replay": True}),
    # Alone, the boost cannot be triggered by revisions: longer episodes are the sign that the world changed
    "boost": Lever("boost (episode-length trigger)", {"adaptation_boost": {"trigger": "episode_length"}}),
    "boost_td": Lever("boost (TD-error trigger)", {"adaptation_boost": {"trigger": "td_error"}}),
    "visible": Lever("visible closures", env_kwargs={"visible_closures": True}),
    "revision_boost": Lever(
        "revision + boost (revision trigger)",
        {"experience_revision": True, "adaptation_boost": {"trigger": "revision"}},
    ),
    "all": Lever("all levers (revision, PER, boost on revision, visible)", _ALL_LEVERS, {"visible_closures": True}),
    "blocked": Lever("blocked-action target", {"blocked_action_target": True}),
    "revision_blocked": Lever(
        "revision + blocked-action target", {"experience_revision": True, "blocked_action_target": True}
    ),
    "revision_blocked_visible": Lever(
        "revision + blocked-action target + visible closures",
        {"experience_revision": True, "blocked_action_target": True},
        {"visible_closures": True},
    ),
    "revision_blocked_per": Lever(
        "revision + blocked-action target + prioritised replay",
        {"experience_revision": True, "blocked_action_target": True, "prioritized_replay": True},
    ),
}


def quick_env_kwargs() -> dict[str, Any]:
    """Cheap env settings for smoke runs: pixel features of 64x48 views (no CNN, views rendered in seconds)."""
    from campusnav_env.rendering.street_view import RenderSettings

    return {"encoder": "pixels", "render_settings": RenderSettings(width=64, height=48)}


def machine_line(runs: str = "runs one after another in one process") -> str:
    """The Markdown line describing the machine a results file was measured on."""
    import os
    import platform

    return (
        f"Machine: {platform.platform()}, {platform.machine()}, {os.cpu_count()} cores (shared: another benchmark may "
        f"run on the other core), 1 torch thread; {runs}."
    )
