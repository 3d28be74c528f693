"""Imported first by every Python code block of the docs that ``tests/test_docs.py`` runs: the same code on a small
budget, so that the blocks run in seconds and the docs cannot drift from the code.

- every ``learn()`` (SB3's off- and on-policy algorithms, and so DCQN, DQN, QR-DQN, with or without the route memory)
  trains at most ``DOCS_MAX_STEPS`` env steps (default 200);
- the CampusNav envs are built with the cheap ``pixels`` encoder on 64 x 48 views, no progress bar, and the city
  env on 120 intersections, unless the block says otherwise.

``DOCS_FULL=1`` leaves everything as written (the blocks' own budgets: minutes to hours).
"""

from __future__ import annotations

import os
from typing import Any

import gymnasium

MAX_STEPS = int(os.environ.get("DOCS_MAX_STEPS", "200"))
_SMALL_VIEWS = {"render_settings": {"width": 64, "height": 48}, "progress": False}


def _capped(learn: Any) -> Any:
    def capped_learn(self: Any, total_timesteps: int, *args: Any, **kwargs: Any) -> Any:
        return learn(self, min(int(total_timesteps), MAX_STEPS), *args, **kwargs)

    return capped_learn


def _cheap_make(make: Any) -> Any:
    def cheap_make(env_id: Any, *args: Any, **kwargs: Any) -> Any:
        if isinstance(env_id, str) and env_id.startswith("CampusNav"):
            kwargs.setdefault("encoder", "pixels")
            view_build = kwargs.get("view_build")
            if view_build is None or isinstance(view_build, dict):
                kwargs["view_build"] = {**_SMALL_VIEWS, **(view_build or {})}
            if env_id == "CampusNavCity-v0":
                kwargs.setdefault("n_intersections", 120)
        return make(env_id, *args, **kwargs)

    return cheap_make


if os.environ.get("DOCS_FULL") != "1":
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

    OffPolicyAlgorithm.learn = _capped(OffPolicyAlgorithm.learn)  # type: ignore[method-assign]
    OnPolicyAlgorithm.learn = _capped(OnPolicyAlgorithm.learn)  # type: ignore[method-assign]
    gymnasium.make = _cheap_make(gymnasium.make)  # what `gym.make` and SB3's env strings call
