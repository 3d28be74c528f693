"""What the CampusNav benchmarks share: the tasks, the agents compared, the lever sets of the closure benchmarks, and
the goal conditions of the any-goal benchmarks (``unseen_goals.py``, ``goal_pictures.py``).

A *task* is a map and its goals (the built-in campus with one or four goals, a generated campus of a few hundred
intersections, or a 1,000-intersection city) with the shipped YAML entry that trains on it. A *variant* is an agent:
DCQN as shipped, DCQN without the heading-relative critics (the network SB3's DQN can have too), SB3's DQN with the
same settings, DCQN with the paper's settings, and DQN, QR-DQN and DCQN wearing the route memory
(:func:`sb3_dcqn.with_route_memory`: an entry that sets ``route_memory`` builds the memory-wearing class). A *lever
set* is a combination of DCQN's re-adaptation levers (:mod:`sb3_dcqn.campusnav.levers`).
Training until solved, the solved bar and the train -> close -> recover loop are the glue's
(:mod:`sb3_dcqn.campusnav.experiments`, :mod:`sb3_dcqn.campusnav.solved`).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
from sb3_contrib import QRDQN
from stable_baselines3 import DQN
from stable_baselines3.common.base_class import BaseAlgorithm

import campusnav_env  # noqa: F401  (registers the CampusNav ids)
from campusnav_env.env import CampusNavEnv
from campusnav_env.features.view_build import ViewBuild, with_view_build
from campusnav_env.maps.campus import generate_campus
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.wrappers import GaussianObservationNoise
from sb3_dcqn import DCQN
from sb3_dcqn.campusnav.levers import LEVERS, LeverSet, with_levers
from sb3_dcqn.route_memory.layer import algorithm_class_for
from sb3_dcqn.zoo_entry import ZooEntry, load_zoo_entry
from sb3_dcqn.zoo_files import default_hyperparams_path, paper_hyperparams_path


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
        kwargs = with_view_build({**entry.env_kwargs, **self.env_kwargs, **env_kwargs}, progress=False)
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
        # The 1,000-intersection city (EfficientNet-Lite0 features, as shipped), its entry's start curriculum
        Task("city", "CampusNavCity-v0 (1,000 nodes, 1 goal)", "CampusNavCity-v0", "CampusNavCity-v0", 1_000,
             max_steps=100_000, budget_seconds=240, goal_seconds=60, eval_freq=2_500),
        # A smoke run: small street views, a cheap pixel encoder, a few hundred steps (tests and --quick)
        Task("quick", "smoke run (CampusNav-v0, 64x48 pixel features)", "CampusNav-v0", "CampusNav-v0", 101,
             max_steps=600, budget_seconds=30, goal_seconds=30, eval_freq=300,
             env_kwargs={"encoder": "pixels", "view_build": ViewBuild(render_settings=RenderSettings(64, 48))}),
    )
}  # fmt: skip


@dataclass(frozen=True)
class World:
    """
    How the pictures of a task's map behave between visits: fixed (the paper's reproduction: every visit sees the
    same views), fresh Gaussian noise on the current views at every observation (:class:`GaussianObservationNoise`,
    sigma in units of a standardised feature), or ``K`` renders per view drawn per visit (``view_variation``: hours,
    passing cars, a few degrees of camera yaw), or both. The route evaluation sees the same world (it goes through
    the wrappers and draws the renders as training does).

    :param name: Short name (command line, results)
    :param noise: Sigma of the noise on the current views (0: none)
    :param variation: The env's ``view_variation`` (:class:`~campusnav_env.rendering.variation.ViewVariation`'s
        fields: ``renders``, ``hours``, ``yaw_jitter_deg``, ``seed``...; ``None``: fixed views)
    """

    name: str
    noise: float = 0.0
    variation: dict[str, Any] | None = None

    def make_env(self, task: Task, entry: ZooEntry) -> gym.Env:
        """The task's env in this world."""
        env = task.make_env(entry, **({} if self.variation is None else {"view_variation": dict(self.variation)}))
        if not self.noise:
            return env
        current = "views" if "views" in env.observation_space.spaces else "observation"  # the goal env's views
        return GaussianObservationNoise(env, self.noise, keys=[current])


# The harder varied world of issue 46: twice the renders, an hour window into dawn and dusk, twice the yaw, and a
# variation seed no entry or test was tuned on
HARDER_VARIATION = {"renders": 16, "hours": (6.0, 20.0), "yaw_jitter_deg": 6.0, "seed": 7}

# The severity sweep of issue 46: the harder world with one axis at a time made easier or harder (the middle value of
# each is the harder world's own)
SEVERITY_AXES: dict[str, tuple[Any, ...]] = {
    "renders": (8, 16, 32),
    "hours": ((9.0, 17.0), (6.0, 20.0), (0.0, 24.0)),
    "yaw_jitter_deg": (3.0, 6.0, 12.0),
    "noise": (0.0, 0.05, 0.1),
}


def _severity_worlds() -> list[World]:
    """The harder world, and one world per other value of each severity axis (named by the value changed)."""
    worlds = [World("harder", variation=HARDER_VARIATION)]
    for axis, values in SEVERITY_AXES.items():
        for value in values:
            if axis == "noise":
                if value:
                    worlds.append(World(f"harder, noise {value:g}", noise=value, variation=HARDER_VARIATION))
            elif value != HARDER_VARIATION[axis]:
                shown = f"{value[0]:g}-{value[1]:g}" if axis == "hours" else f"{value:g}"
                name = f"harder, {axis.removesuffix('_jitter_deg')} {shown}"
                worlds.append(World(name, variation={**HARDER_VARIATION, axis: value}))
    return worlds


SEVERITY_SWEEP = tuple(world.name for world in _severity_worlds())
WORLDS = {
    world.name: world
    for world in (
        World("fixed"),
        World("noise 0.01", noise=0.01),
        World("noise 0.05", noise=0.05),
        World("variation 8", variation={"renders": 8}),
        *_severity_worlds(),
    )
}


@dataclass(frozen=True)
class Variant:
    """
    An agent: an algorithm, the hyperparameter file it reads, and changes to its entry.

    :param name: Name in tables
    :param algo: ``"DCQN"``, ``"DQN"`` or ``"QRDQN"`` (wearing the route memory where the entry sets ``route_memory``)
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
        return ZooEntry(task.max_steps, hyperparams, env_kwargs, entry.n_envs, entry.callbacks)

    def make_model(self, env: gym.Env, entry: ZooEntry, seed: int, **kwargs: Any) -> BaseAlgorithm:
        hyperparams = {**entry.hyperparams, **kwargs}
        algo = algorithm_class_for({"DCQN": DCQN, "DQN": DQN, "QRDQN": QRDQN}[self.algo], hyperparams)
        return algo(env=env, seed=seed, device="cpu", **hyperparams)


# DCQN's policy_kwargs that SB3's DQN and sb3-contrib's QR-DQN policies do not take
OTHER_POLICIES = ("heading_key", "share_features_extractor")
VARIANTS = {
    variant.name: variant
    for variant in (
        Variant("DCQN"),
        # The critics read the heading like any other input: the network SB3's DQN can have too
        Variant("DCQN, no heading_key", policy_overrides={"heading_key": None}),
        # The route memory on an entry without it (CampusNavMulti-v0's has it: "DCQN, critics alone" leaves it out)
        Variant("DCQN + memory", overrides={"route_memory": True}),
        Variant("DCQN, critics alone", overrides={"route_memory": False}),
        Variant("DQN", algo="DQN", drop_policy_kwargs=OTHER_POLICIES),
        # What the twin critics add once the memory routes: the same memory worn by DQN, QR-DQN and DCQN
        Variant("DQN + memory", algo="DQN", drop_policy_kwargs=OTHER_POLICIES, overrides={"route_memory": True}),
        Variant(
            "QRDQN + memory",
            algo="QRDQN",
            drop_policy_kwargs=OTHER_POLICIES,
            overrides={"route_memory": True},
            # The RL Zoo's quantiles for its small discrete tasks: with QR-DQN's default 200 an env step on the city
            # (a gradient step on 256 every 4) cost 110 ms against DQN's 4 ms (2,185 steps in 240 s), and the time
            # budget measured that, not the memory
            policy_overrides={"n_quantiles": 10},
        ),
        Variant("DCQN, paper settings", paper=True),
        # The CampusNav-v0 entry before the learning-speed work: full 1280-d features, width 256, lr 1e-4
        Variant(
            "DCQN, previous settings",
            overrides={"learning_rate": 1e-4},
            policy_overrides={
                "features_extractor_kwargs": {"embed_dim": 256, "features_dim": 256},
                "net_arch": [256],
                "heading_key": None,
            },
            env_overrides={"view_dim": None},
        ),
    )
}


# The memory row's name before the memory was a layer (earlier results files and command lines)
VARIANTS["DCQN, route memory"] = VARIANTS["DCQN + memory"]


# ------------------------------------------------------------------------------------------------ closure experiments
def lever_entry(lever_set: LeverSet, task: Task) -> ZooEntry:
    """The shipped DCQN entry for ``task`` with a lever set's DCQN and env options (``sb3_dcqn.campusnav.levers``)."""
    return with_levers(VARIANTS["DCQN"].entry(task), lever_set.levers)


# The closure benchmarks' rows: combinations of the levers of sb3_dcqn.campusnav.levers, named by the levers' names
# (the keys are the runs files' "lever" field). The adaptation boost left DCQN for an SB3 callback
# (sb3_dcqn.adaptation_boost): the runs made with DCQN's old option ("boost", "all") stay in the runs files as history;
# the callback's have keys of their own.
LEVER_SETS = {
    "baseline": LeverSet("baseline (DCQN as shipped)"),
    "revision": LeverSet(LEVERS["revision"].name, ("revision",)),
    "prioritized": LeverSet(LEVERS["prioritized"].name, ("prioritized",)),
    "visible": LeverSet(LEVERS["visible"].name, ("visible",)),
    "blocked": LeverSet(LEVERS["blocked"].name, ("blocked",)),
    "revision_blocked": LeverSet("revision + blocked-action target", ("revision", "blocked")),
    "revision_blocked_visible": LeverSet(
        "revision + blocked-action target + visible closures", ("revision", "blocked", "visible")
    ),
    "revision_blocked_prioritized": LeverSet(
        "revision + blocked-action target + prioritized replay", ("revision", "blocked", "prioritized")
    ),
    # What "all" was without the boost, and with the boost as a callback
    "revision_prioritized_visible": LeverSet(
        "revision + prioritized replay + visible closures", ("revision", "prioritized", "visible")
    ),
    "revision_prioritized_visible_boost": LeverSet(
        "revision + prioritized replay + visible closures + boost (revision trigger)",
        ("revision", "prioritized", "visible", "boost_on_revision"),
    ),
    "boost_callback": LeverSet("adaptation boost (episode-length trigger, callback)", ("boost",)),
    "route_memory": LeverSet("route memory + exploration toward the untried", ("route_memory",)),
    "route_memory_revision_blocked": LeverSet(
        "route memory + exploration toward the untried + revision + blocked-action target",
        ("route_memory", "revision", "blocked"),
    ),
}


def quick_env_kwargs() -> dict[str, Any]:
    """Cheap env settings for smoke runs: pixel features of 64x48 views (no CNN, views rendered in seconds)."""
    return {"encoder": "pixels", "view_build": ViewBuild(render_settings=RenderSettings(width=64, height=48))}


# ------------------------------------------------------------------------------------------------ any-goal benchmarks
# The share of intersections held out of training as goals (campusnav_env.goal_env.held_out_split)
HELD_OUT_FRACTION = 0.2
# The conditions the goal_photos lever pictures training goals in (None: as the agent's views, noon), and those the
# appearance test pictures them in: none of the test's is a training condition
TRAINING_PHOTOS = (None, *(RenderSettings(time_of_day=hour) for hour in (7.0, 16.0, 20.5)))
APPEARANCES = {
    "morning (8:30)": RenderSettings(time_of_day=8.5),
    "evening (17:30)": RenderSettings(time_of_day=17.5),
    "night (19:30)": RenderSettings(time_of_day=19.5),
    "passing cars": RenderSettings(cars=True),
    "night + cars": RenderSettings(time_of_day=19.5, cars=True),
    "20:30 + cars": RenderSettings(time_of_day=20.5, cars=True),
    "22:30 + cars": RenderSettings(time_of_day=22.5, cars=True),
}
