"""Gymnasium registration of the CampusNav ids (run on ``import campusnav_env``)."""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from campusnav_env.maps.campus import GOALS

ENTRY_POINT = "campusnav_env.env:CampusNavEnv"
ENV_IDS = {
    "CampusNav-v0": {"goals": [GOALS[0]]},  # single goal: Dreese Lab
    "CampusNavMulti-v0": {"goals": list(GOALS)},  # the paper's four goals
}


def register_envs() -> None:
    """Register ``CampusNav-v0`` and ``CampusNavMulti-v0`` (idempotent). The env truncates after ``max_steps``."""
    for env_id, kwargs in ENV_IDS.items():
        if env_id not in registry:
            register(id=env_id, entry_point=ENTRY_POINT, kwargs=kwargs)
