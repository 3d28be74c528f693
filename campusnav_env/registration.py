"""Gymnasium registration of the CampusNav ids (run on ``import campusnav_env``)."""

from __future__ import annotations

from typing import Any

from gymnasium.envs.registration import register, registry

from campusnav_env.maps.campus import GOALS

CAMPUSNAV = "campusnav_env.env:CampusNavEnv"
CAMPUSNAV_GOAL = "campusnav_env.goal_env:CampusNavGoalEnv"
CAMPUSNAV_CITY = "campusnav_env.city_env:CampusNavCityEnv"
# id -> (entry point, default arguments)
ENV_IDS: dict[str, tuple[str, dict[str, Any]]] = {
    "CampusNav-v0": (CAMPUSNAV, {"goals": [GOALS[0]]}),  # single goal: Dreese Lab
    "CampusNavMulti-v0": (CAMPUSNAV, {"goals": list(GOALS)}),  # the paper's four goals
    "CampusNavGoal-v0": (CAMPUSNAV_GOAL, {}),  # any intersection as the goal (goal-env convention, for HER)
    # A generated city (1,000 intersections, seed 0, goal Dreese Lab, max_steps="auto"); no defaults here, so that
    # world= (a real map) can replace n_intersections
    "CampusNavCity-v0": (CAMPUSNAV_CITY, {}),
    # The 10,000-intersection city (its own id, so that it has a YAML entry of its own)
    "CampusNavCity10k-v0": (CAMPUSNAV_CITY, {"n_intersections": 10_000}),
}


def register_envs() -> None:
    """Register the ids of :data:`ENV_IDS` (idempotent)."""
    for env_id, (entry_point, kwargs) in ENV_IDS.items():
        if env_id not in registry:
            register(id=env_id, entry_point=entry_point, kwargs=kwargs)
