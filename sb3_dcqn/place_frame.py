"""What an env declares about its observations' frame, so that a route memory keys places instead of poses.

An env whose observation pictures a *place* the same way whatever the agent's heading, and whose actions are relative
to that heading, can say so in its ``metadata`` under :data:`PLACE_FRAME_KEY` (a plain dict, so the env needs nothing
from this package)::

    metadata = {
        "render_modes": [...],
        "place_frame": {
            "place_keys": ["views"],        # the Dict keys that picture the place (not the heading, not the goal)
            "frame_key": "heading",         # one-hot frame; action a at frame f takes compass slot (f + a) % n
            "reverse_action": 2,            # two-way roads: right after a move, this action leads back
            "views_per_place": 4,           # the place key is this many equal blocks, one per view
            "goal_pictures": {"goal_views": "views"},  # goal keys that picture a place as the place key does
        },
    }

Every entry but ``place_keys`` is optional: without ``frame_key`` the actions are absolute (slot = action), without
``reverse_action`` nothing is inferred about the way back. :func:`place_frame_of` reads the declaration through
Gymnasium wrappers and SB3's vector envs (``get_attr("metadata")``); an env without one gets ``None``, and a memory
then keys its states by the whole observation (poses), as before. The same declaration gives DCQN's critics their
``heading_key`` (:class:`~sb3_dcqn.policies.TwinQNetwork`).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from gymnasium import spaces

__all__ = ["PLACE_FRAME_KEY", "PlaceFrame", "place_frame_of"]

PLACE_FRAME_KEY = "place_frame"
_FIELDS = ("place_keys", "frame_key", "reverse_action", "views_per_place", "goal_pictures")
# Read by earlier memories, which needed to be told that goals could look different; the recogniser now decides per
# picture, so a declaration that still carries it is accepted with a warning
_RETIRED = ("goals_pictured_otherwise",)


@dataclass(frozen=True)
class PlaceFrame:
    """
    An env's declaration of its places and frame (see the module docstring), checked against its spaces.

    :param place_keys: Dict keys that picture the place, whatever the frame
    :param n_slots: Number of compass slots (the actions' number)
    :param frame_key: Key of a one-hot frame the actions are relative to (``None``: absolute actions)
    :param reverse_action: The action that, right after a move, leads back to where the move started (``None``: roads
        are not known to be two-way; needs ``frame_key``)
    :param views_per_place: The place picture is this many equal blocks (views): a place whose pictures change in a
        few views (a barrier) is still recognised by the others
    :param goal_pictures: Goal key -> the place key whose format it pictures a goal place in
    """

    place_keys: tuple[str, ...]
    n_slots: int
    frame_key: str | None = None
    reverse_action: int | None = None
    views_per_place: int = 1
    goal_pictures: Mapping[str, str] = field(default_factory=dict)

    @classmethod
    def from_declaration(
        cls, declaration: Mapping[str, Any], observation_space: spaces.Space, action_space: spaces.Space
    ) -> PlaceFrame:
        """The declaration checked against the env's spaces (a ValueError names the entry that does not fit)."""
        where = f"metadata[{PLACE_FRAME_KEY!r}]"
        retired = sorted(set(declaration) & set(_RETIRED))
        if retired:
            warnings.warn(f"{where}: {retired} no longer read (the memory recognises each goal picture)", stacklevel=2)
        unknown = sorted(set(declaration) - set(_FIELDS) - set(_RETIRED))
        if unknown:
            raise ValueError(f"{where}: unknown entries {unknown}; allowed: {list(_FIELDS)}")
        if not isinstance(observation_space, spaces.Dict):
            raise ValueError(f"{where} needs a Dict observation space, got {observation_space}")
        if not isinstance(action_space, spaces.Discrete):
            raise ValueError(f"{where} needs a Discrete action space, got {action_space}")
        n_slots = int(action_space.n)
        keys = observation_space.spaces
        place_keys = tuple(declaration.get("place_keys") or ())
        frame_key = declaration.get("frame_key")
        if not place_keys or any(key not in keys for key in place_keys):
            raise ValueError(f"{where}: place_keys {list(place_keys)} must be keys of the observation {sorted(keys)}")
        if frame_key is not None:
            if frame_key not in keys or frame_key in place_keys:
                raise ValueError(f"{where}: frame_key {frame_key!r} must be another key of {sorted(keys)}")
            if keys[frame_key].shape != (n_slots,):
                raise ValueError(
                    f"{where}: frame_key {frame_key!r} must be one-hot over the {n_slots} actions, "
                    f"got shape {keys[frame_key].shape}"
                )
        reverse = declaration.get("reverse_action")
        if reverse is not None and (frame_key is None or not 0 <= int(reverse) < n_slots):
            raise ValueError(f"{where}: reverse_action {reverse} must be an action of {action_space}, with a frame_key")
        views = int(declaration.get("views_per_place", 1))
        size = sum(int(keys[key].shape[0]) if keys[key].shape else 1 for key in place_keys)
        if views < 1 or (len(place_keys) != 1 and views != 1) or size % views:
            raise ValueError(
                f"{where}: views_per_place {views} must divide the one place key's size {size} evenly (1 for several)"
            )
        pictures = dict(declaration.get("goal_pictures") or {})
        for goal_key, place_key in pictures.items():
            if goal_key not in keys or place_key not in place_keys or keys[goal_key].shape != keys[place_key].shape:
                raise ValueError(
                    f"{where}: goal_pictures {goal_key!r} -> {place_key!r}: a goal key must picture a place key in its "
                    f"shape ({sorted(keys)}, place keys {list(place_keys)})"
                )
        if len(pictures) > 1 or (pictures and len(place_keys) != 1):
            raise ValueError(f"{where}: goal_pictures takes one goal key for one place key, got {pictures}")
        return cls(
            place_keys=place_keys,
            n_slots=n_slots,
            frame_key=frame_key,
            reverse_action=None if reverse is None else int(reverse),
            views_per_place=views,
            goal_pictures=pictures,
        )

    @property
    def goal_key(self) -> str | None:
        """The goal key whose pictures show a place (``None``: goals only by the transitions that reached them)."""
        return next(iter(self.goal_pictures), None)

    def slot(self, frame: int, action: int) -> int:
        """The slot an action takes at a frame."""
        return (frame + action) % self.n_slots if self.frame_key is not None else action


def place_frame_of(env: Any) -> PlaceFrame | None:
    """
    The place frame an env declares in its metadata (see the module docstring), read through Gymnasium wrappers and
    SB3's vector envs; ``None`` where it declares none. A declaration that does not fit the spaces the caller sees
    (the env wrapped in ``FlattenObservation``, ``FilterObservation`` or ``VecFrameStack``: the metadata passes
    through, the spaces change) means no frame, with one warning naming the misfit.

    :param env: A Gymnasium env, a wrapper, or an SB3 ``VecEnv``
    """
    if env is None:
        return None
    if hasattr(env, "get_attr") and hasattr(env, "num_envs"):  # an SB3 VecEnv: ask its first env
        metadata = env.get_attr("metadata", indices=[0])[0]
    else:
        metadata = getattr(env, "metadata", None)
    declaration = (metadata or {}).get(PLACE_FRAME_KEY)
    if declaration is None:
        return None
    try:
        return PlaceFrame.from_declaration(declaration, env.observation_space, env.action_space)
    except ValueError as misfit:
        warnings.warn(
            f"The env declares a place frame that does not fit the spaces it is seen through ({misfit}): states are "
            "poses (whole observations)",
            stacklevel=2,
        )
        return None
