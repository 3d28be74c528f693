"""Observation wrappers for any Gymnasium env (gymnasium and numpy only), and their batched use by evaluators.

:class:`GaussianObservationNoise` adds fresh Gaussian noise to every observation: the simplest world in which no two
visits to a place look alike, for any env with a Box or a Dict-of-Box observation space (CampusNav's features are
standardised, so a ``sigma`` is in units of a feature's spread over the map's views).

Evaluators that query a policy on batches of observations built by the env itself (CampusNav's route evaluation,
:meth:`~campusnav_env.env.CampusNavEnv.observations_at`) must show the policy what the wrappers would have shown it:
:func:`wrapped_observations` passes such a batch through the observation wrappers of an env's chain, innermost first
(a wrapper's batched ``observations(batch)`` where it has one, else its ``observation`` item by item), and
:func:`observations_vary` says whether any wrapper makes two visits to one state look different.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

__all__ = ["GaussianObservationNoise", "any_wrapper_varies", "observation_wrappers", "wrapped_observations"]

# Mixed into the reset seed, so that the noise is not the env's own draws (an env seeded with the same seed)
NOISE_STREAM = 0x6E6F697365


class GaussianObservationNoise(gym.ObservationWrapper[Any, Any, Any]):
    """
    Add fresh Gaussian noise of standard deviation ``sigma`` to every observation: to a ``Box`` observation, or to
    the ``keys`` of a ``Dict`` of ``Box`` es (default: every key); the other keys pass unchanged.

    The noise comes from the wrapper's own generator, seeded by ``reset(seed=...)`` (from the seed and
    :data:`NOISE_STREAM`, so that it is not the env's own random stream), and unseeded until then: ``reset`` with the
    same seed gives the same noise (SB3's vector envs seed every env at their first reset). Float boxes that get noise
    span the float32 range from then on (the noise may leave the env's bounds); integer boxes (images) are rounded
    and clipped to their bounds, so that their space is unchanged.

    :meth:`observations` adds noise to a batch of observations (a leading batch axis), each with noise of its own: the
    route evaluator calls it (see :func:`wrapped_observations`), so that evaluation sees what training sees.

    :param env: The env
    :param sigma: Standard deviation of the noise (>= 0; 0 leaves the observations as they are)
    :param keys: The ``Dict`` keys that get noise (default: every key); must be None for a ``Box`` observation
    :raises ValueError: if ``sigma`` is negative or not finite, or a key is not one of the observation's
    :raises TypeError: if the observation space is neither a ``Box`` nor a ``Dict`` whose noised keys are ``Box`` es
    """

    def __init__(self, env: gym.Env[Any, Any], sigma: float, keys: Sequence[str] | None = None) -> None:
        super().__init__(env)
        if isinstance(sigma, bool) or not isinstance(sigma, (int, float, np.number)) or not math.isfinite(sigma):
            raise ValueError(f"GaussianObservationNoise: sigma must be a finite number >= 0, got {sigma!r}")
        if sigma < 0:
            raise ValueError(f"GaussianObservationNoise: sigma must be >= 0, got {sigma!r}")
        self.sigma = float(sigma)
        space = env.observation_space
        if isinstance(space, spaces.Box):
            if keys is not None:
                raise ValueError(f"GaussianObservationNoise: keys {list(keys)} given, but the observation is a Box")
            self.keys: tuple[str, ...] | None = None
            self.observation_space = _noised_space(space)
        elif isinstance(space, spaces.Dict):
            self.keys = tuple(space.spaces) if keys is None else _checked_keys(space, keys)
            self.observation_space = spaces.Dict(
                {key: _noised_space(sub) if key in self.keys else sub for key, sub in space.spaces.items()}
            )
        else:
            raise TypeError(
                f"GaussianObservationNoise needs a Box or a Dict of Boxes observation space, got {type(space).__name__}"
            )
        self._rng = np.random.default_rng()

    @property
    def observations_vary(self) -> bool:
        """Whether two observations of one state differ (any noise at all)."""
        return self.sigma > 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self._rng = np.random.default_rng([seed, NOISE_STREAM])
        return super().reset(seed=seed, options=options)

    def observation(self, observation: Any) -> Any:
        """The observation with fresh noise on the noised keys."""
        return self.observations(observation)

    def observations(self, batch: Any) -> Any:
        """
        Observations with fresh noise: one observation, or a batch of them along a leading axis (each entry its own
        noise; the noise only needs the values' shape).

        :param batch: An observation or a batch, as the env's space gives it (a dict for a ``Dict`` space)
        :return: the same structure, noise added to the noised keys
        """
        if self.keys is None:
            return self._noised(batch, self.env.observation_space)
        space = self.env.observation_space
        return {key: self._noised(value, space[key]) if key in self.keys else value for key, value in batch.items()}

    def _noised(self, value: np.ndarray, space: spaces.Box) -> np.ndarray:
        value = np.asarray(value)
        if self.sigma == 0:
            return value
        noised = value + self._rng.normal(0.0, self.sigma, size=value.shape)
        if np.issubdtype(space.dtype, np.integer):  # images stay valid images
            return np.clip(np.rint(noised), space.low, space.high).astype(space.dtype)
        return noised.astype(space.dtype)


def _checked_keys(space: spaces.Dict, keys: Sequence[str]) -> tuple[str, ...]:
    """The noised keys of a Dict space, each one of its keys and a Box."""
    if isinstance(keys, str):
        raise TypeError(f"GaussianObservationNoise: keys must be a sequence of keys, got the string {keys!r}")
    unknown = [key for key in keys if key not in space.spaces]
    if unknown:
        raise ValueError(f"GaussianObservationNoise: keys {unknown} are not observation keys {list(space.spaces)}")
    not_boxes = [key for key in keys if not isinstance(space[key], spaces.Box)]
    if not_boxes:
        raise TypeError(f"GaussianObservationNoise: keys {not_boxes} are not Box observations")
    return tuple(keys)


def _noised_space(space: spaces.Box) -> spaces.Box:
    """The space of a Box's noised values: a float box spans its dtype's range, an integer box stays itself."""
    if np.issubdtype(space.dtype, np.integer):
        return space
    info = np.finfo(space.dtype)
    return spaces.Box(float(info.min), float(info.max), shape=space.shape, dtype=space.dtype)


def observation_wrappers(env: gym.Env[Any, Any]) -> list[gym.ObservationWrapper[Any, Any, Any]]:
    """The observation wrappers of an env's chain, innermost first (the order they act in)."""
    found = []
    while isinstance(env, gym.Wrapper):
        if isinstance(env, gym.ObservationWrapper):
            found.append(env)
        env = env.env
    return found[::-1]


def wrapped_observations(env: gym.Env[Any, Any], batch: Any) -> Any:
    """
    A batch of the unwrapped env's observations as ``env``'s observation wrappers would show them to the agent.

    :param env: The env as the agent sees it (wrappers and all)
    :param batch: Observations of ``env.unwrapped`` along a leading batch axis (a dict of arrays for a Dict space)
    :return: the batch through every observation wrapper, innermost first: a wrapper's ``observations(batch)`` where
        it has one, else its ``observation`` applied to each entry and the results stacked
    """
    for wrapper in observation_wrappers(env):
        batched = getattr(wrapper, "observations", None)
        batch = batched(batch) if callable(batched) else _item_by_item(wrapper, batch)
    return batch


def any_wrapper_varies(env: gym.Env[Any, Any]) -> bool:
    """Whether some wrapper of ``env``'s chain shows two visits to one state differently (``observations_vary``)."""
    return any(getattr(wrapper, "observations_vary", False) for wrapper in observation_wrappers(env))


def _item_by_item(wrapper: gym.ObservationWrapper[Any, Any, Any], batch: Any) -> Any:
    """A wrapper without a batched method, applied to each entry of a batch and the results stacked."""
    if isinstance(batch, dict):
        size = len(next(iter(batch.values())))
        entries = [{key: value[i] for key, value in batch.items()} for i in range(size)]
    else:
        entries = list(batch)
    items = [wrapper.observation(entry) for entry in entries]
    if items and isinstance(items[0], dict):
        return {key: np.stack([item[key] for item in items]) for key in items[0]}
    return np.stack(items)
