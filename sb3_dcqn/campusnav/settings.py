"""The env a model trains on (:class:`EnvSettings`, as ``<model>.env.json`` stores it) and the envs made from it.

Importing this module is cheap (no torch, no CampusNav): the command line reads its defaults at start-up.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv

    from campusnav_env import CampusNavEnv
    from campusnav_env.maps.road_graph import RoadGraph

__all__ = [
    "DEFAULT_ENCODER",
    "DEFAULT_ENV",
    "EnvSettings",
    "campus_of",
    "campusnav_env_ids",
    "load_map",
    "make_env",
    "make_training_envs",
]

DEFAULT_ENV = "CampusNav-v0"
DEFAULT_ENCODER = "efficientnet-lite0"


@dataclass(frozen=True)
class EnvSettings:
    """
    The env a model is trained on, as the command line builds it (and as ``<model>.env.json`` stores it).

    :param env_id: Gymnasium id (``CampusNav-v0``, ``CampusNavMulti-v0``)
    :param env_kwargs: ``env_kwargs`` of the hyperparameter entry (e.g. ``view_dim``)
    :param encoder: View encoder name
    :param encoder_weights: Weights file of the encoder (ResNet-50), if any
    :param render_size: Street-view size ``(width, height)``; ``None``: the renderer's default (640 x 480)
    :param map_path: A GraphML road network the env is built on (``world=``, :func:`load_map`) instead of its own map
    :param map_coords: How the map's x/y are read: ``"auto"`` (the file's ``crs``, else a plausible-extent guess that
        warns), ``"lonlat"`` or ``"projected"`` (metres); see :func:`campusnav_env.maps.osm.import_networkx`
    :param encoder_random_init: ResNet-50 without weights, random features asked for (``--encoder-random-init``)
    """

    env_id: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    encoder: str = DEFAULT_ENCODER
    encoder_weights: str | None = None
    render_size: tuple[int, int] | None = None
    map_path: str | None = None
    encoder_random_init: bool = False
    map_coords: str = "auto"

    def make_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for ``gym.make``."""
        from campusnav_env.features.view_build import ViewBuild
        from campusnav_env.rendering.street_view import RenderSettings

        kwargs: dict[str, Any] = {**self.env_kwargs, "encoder": self.encoder}
        if self.map_path is not None:
            kwargs["world"] = load_map(self.map_path, self.map_coords)
        build: dict[str, Any] = {}  # over the entry's own view_build
        if self.encoder_weights is not None:
            build["encoder_kwargs"] = {"weights_path": self.encoder_weights}
        elif self.encoder_random_init:
            build["encoder_kwargs"] = {"random_init": True}
        if self.render_size is not None:
            build["render_settings"] = RenderSettings(width=self.render_size[0], height=self.render_size[1])
        if build:
            kwargs["view_build"] = ViewBuild.of(kwargs.get("view_build"), **build)
        return kwargs

    def to_json(self) -> dict[str, Any]:
        return {
            "env": self.env_id,
            "env_kwargs": self.env_kwargs,
            "encoder": self.encoder,
            "encoder_weights": self.encoder_weights,
            "render_size": None if self.render_size is None else list(self.render_size),
            "map": self.map_path,
            "encoder_random_init": self.encoder_random_init,
            "map_coords": self.map_coords,
        }

    @classmethod
    def from_json(cls, document: dict[str, Any]) -> EnvSettings:
        size = document.get("render_size")
        return cls(
            env_id=str(document["env"]),
            env_kwargs=dict(document.get("env_kwargs") or {}),
            encoder=str(document.get("encoder", DEFAULT_ENCODER)),
            encoder_weights=document.get("encoder_weights"),
            render_size=None if size is None else (int(size[0]), int(size[1])),
            map_path=document.get("map"),
            encoder_random_init=bool(document.get("encoder_random_init", False)),
            map_coords=str(document.get("map_coords", "auto")),
        )

    def describe(self) -> str:
        """E.g. ``"CampusNav-v0, encoder pixels, views 64x48"`` (``"CampusNav-v0 on columbus.graphml, ..."``)."""
        size = "640x480" if self.render_size is None else f"{self.render_size[0]}x{self.render_size[1]}"
        where = "" if self.map_path is None else f" on {Path(self.map_path).name}"
        random = " (random init)" if self.encoder_random_init else ""
        return f"{self.env_id}{where}, encoder {self.encoder}{random}, views {size}"


def campusnav_env_ids() -> list[str]:
    """
    The registered CampusNav ids, in order: the keys of :data:`campusnav_env.registration.ENV_IDS`, the table
    ``import campusnav_env`` registers with Gymnasium.

    Read from the module's source, not imported: importing ``campusnav_env`` imports torch, and ``--help`` (which
    lists these ids) should answer at once. ``tests/test_campusnav_cli_goal_env.py`` checks them against Gymnasium's
    registry.

    :raises RuntimeError: if the table cannot be found
    """
    import ast
    from importlib.util import find_spec

    spec = find_spec("campusnav_env")  # a top-level package: found without being imported
    locations = [] if spec is None or spec.submodule_search_locations is None else spec.submodule_search_locations
    for folder in locations:
        source = Path(folder) / "registration.py"
        if source.is_file():
            for node in ast.walk(ast.parse(source.read_text(encoding="utf-8"))):
                if isinstance(node, ast.AnnAssign | ast.Assign) and isinstance(node.value, ast.Dict):
                    targets = [node.target] if isinstance(node, ast.AnnAssign) else node.targets
                    if any(isinstance(t, ast.Name) and t.id == "ENV_IDS" for t in targets):
                        return [k.value for k in node.value.keys if isinstance(k, ast.Constant)]
    raise RuntimeError("cannot find campusnav_env.registration.ENV_IDS (is campusnav_env installed?)")


def load_map(path: str, coords: str = "auto") -> RoadGraph:
    """
    The road network of a GraphML file (:func:`campusnav_env.maps.osm.load_graphml`), read once per process for each
    version of the file (every training env shares it; each env keeps its own closures).

    :param path: The GraphML file
    :param coords: How its x/y are read (``"auto"``, ``"lonlat"``, ``"projected"``)
    :raises FileNotFoundError: no such file
    :raises ValueError, KeyError: not a road network (see :func:`~campusnav_env.maps.osm.import_networkx`)
    """
    file = Path(path).resolve()
    stat = file.stat() if file.is_file() else None
    return _load_map(str(file), None if stat is None else (stat.st_mtime_ns, stat.st_size), coords)


@functools.lru_cache(maxsize=4)
def _load_map(path: str, version: tuple[int, int] | None, coords: str) -> RoadGraph:
    from campusnav_env.maps.osm import load_graphml

    graph = load_graphml(path, coords=coords)
    assert not isinstance(graph, tuple)  # no return_mapping
    return graph


def campus_of(env: gym.Env) -> CampusNavEnv:
    """
    The ``CampusNavEnv`` inside ``env`` (its wrappers removed).

    :raises TypeError: if it is another env
    """
    from campusnav_env.callbacks import campus_env

    return campus_env(env)


def make_env(settings: EnvSettings) -> CampusNavEnv:
    """One env, for evaluating and drawing."""
    import gymnasium as gym

    import campusnav_env  # noqa: F401  (registers the CampusNav ids)

    return campus_of(gym.make(settings.env_id, **settings.make_kwargs()))


def make_training_envs(settings: EnvSettings, n_envs: int, seed: int) -> DummyVecEnv:
    """Training envs (each in a ``Monitor``); the route evaluation shares the first one."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv

    import campusnav_env  # noqa: F401  (registers the CampusNav ids)

    venv = make_vec_env(settings.env_id, n_envs=n_envs, seed=seed, env_kwargs=settings.make_kwargs())
    assert isinstance(venv, DummyVecEnv)
    campus_of(venv.envs[0])
    return venv
