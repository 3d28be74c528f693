"""CampusNavCity: CampusNav on a large generated city (or a real map), with an episode cap that grows with the map."""

from __future__ import annotations

from collections.abc import Sequence
from os import PathLike
from typing import Any

from campusnav_env.env import CampusNavEnv
from campusnav_env.maps.campus import generate_city
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.maps.road_graph import RoadGraph

DEFAULT_CITY_INTERSECTIONS = 1_000
DEFAULT_MAP_SEED = 0


class CampusNavCityEnv(CampusNavEnv):
    """
    ## Description
    CampusNav (see :class:`~campusnav_env.env.CampusNavEnv`) on a city: a generated street network of
    ``n_intersections`` intersections (default 1,000) at the built-in campus's street density
    (:func:`~campusnav_env.maps.campus.generate_city`: 2.5 km x 1.7 km times ``sqrt(n_intersections / 101)``, so a
    block is as large as on the campus at every size), or a real map passed as ``world`` (e.g. an OpenStreetMap graph
    from :mod:`campusnav_env.maps.osm`). The agent sees four street views per intersection and must drive to the
    goal, given as the goal's views, by the shortest route, re-routing when roads close (:meth:`close_road`). The
    generator places the goal landmarks (Dreese Lab, Town house, Cinema, Intramural fields) at every size.

    ## Action Space
    ``Discrete(4)``, relative to the agent's heading: 0 forward, 1 right, 2 back, 3 left (as in CampusNav).

    ## Observation Space
    As in CampusNav: ``observation_mode="features"`` (default), a ``Dict`` of ``"views"`` (``Box(4 * D,)`` float32,
    the current views N, E, S, W), ``"goal_views"`` (``Box(4 * D,)`` float32, the goal's views) and ``"heading"``
    (``Box(0, 1, (4,))``, one-hot); ``observation_mode="image"``, a ``Box(0, 255, (3, 2h, 4w))`` uint8 image. D is the
    encoder's size, or ``view_dim``; on a large map, ``view_dim`` (e.g. 64) keeps the replay buffer small.

    ## Rewards
    As in CampusNav: ``goal_reward`` (+1.0) on reaching the goal; ``collision_penalty`` (-0.01) for an action with no
    open road that way (the agent stays); ``step_penalty`` (-0.005) for every other move.

    ## Starting State
    A uniformly random intersection that can reach the goal over open roads (other than the goal), with a uniformly
    random heading; with :attr:`start_distance_limit` ``k``, only intersections within ``k`` hops of the goal (a
    near-to-far curriculum, see :class:`~campusnav_env.callbacks.StartCurriculumCallback`: on a city most random
    starts are too far for an untrained agent to ever reach the goal). ``reset(options=...)`` accepts ``start``,
    ``heading`` and ``goal``.

    ## Episode End
    Terminated on reaching the goal; truncated after ``max_steps`` steps. The default, ``"auto"``, grows with the map:
    ``max(200, 4 x the longest shortest route)`` from any start to any of the env's goals, in hops, on the open map
    (:func:`~campusnav_env.env.auto_max_steps`); for seed-0 cities and Dreese Lab, 200 at 1,000 intersections
    (longest route 45 hops) and 528 at 10,000 (132 hops). It is computed once, at construction: closures made later do
    not change it. An int fixes the cap.

    ## Information
    As in CampusNav: ``node``, ``heading``, ``goal``, ``goal_node``, ``shortest_distance``, ``collision``,
    ``action_mask`` and, on the last step, ``is_success``.

    ## Arguments
    ```python
    gym.make("CampusNavCity-v0")                                  # 1,000 intersections, seed 0, goal Dreese Lab
    gym.make("CampusNavCity-v0", n_intersections=10_000, map_seed=3, goals=["Dreese Lab", "Cinema"], view_dim=64)
    gym.make("CampusNavCity-v0", world=load_graphml("columbus.graphml"), goals=["Library"])  # a real map
    ```
    - ``n_intersections``: intersections of the generated city (at least 8; default 1,000).
    - ``map_seed``: seed of the generated streets and landmarks (default 0); ``world_seed`` seeds the buildings and
      trees around them, as in CampusNav.
    - ``world``: a :class:`~campusnav_env.maps.road_graph.RoadGraph`, a
      :class:`~campusnav_env.maps.navigation.NavigationGraph` or the path of a GraphML road network to use instead of
      a generated city (then ``n_intersections`` and ``map_seed`` must not be given); ``map_coords`` says how a
      GraphML file's x / y are read, as in :class:`~campusnav_env.env.CampusNavEnv`.
    - ``goals``: one or several landmark names or node ids (default ``"Dreese Lab"``).
    - ``max_steps``: ``"auto"`` (default, see Episode End) or an int.
    - ``view_build``: as in :class:`~campusnav_env.env.CampusNavEnv`, except that the views are rendered at the size
      the CNN consumes unless it says otherwise (``fit_views_to_encoder`` None means True here, unlike CampusNav:
      about 1.8x less work per view, which a city's cold build needs).
    - every other argument as in :class:`~campusnav_env.env.CampusNavEnv` (``observation_mode``, ``encoder``,
      ``view_dim``, ``view_variation``, rewards, ``render_mode``, ``visible_closures``).

    Building the env renders and encodes four views per intersection (cached on disk, ``cache_dir``): at 10,000
    intersections a cold build takes minutes with ``encoder="pixels"`` and, with EfficientNet-Lite0, what
    ``benchmarks/scale_world_build.py`` measures (worker processes, one per core, views at the CNN's size).

    ## Version History
    * v0: Initial version (CampusNav's arguments about building the views since gathered into ``view_build``, which
      replaced this env's ``fit_views_to_encoder``; ``view_variation`` added).
    """

    fits_views_to_encoder = True

    def __init__(
        self,
        n_intersections: int | None = None,
        map_seed: int | None = None,
        world: RoadGraph | NavigationGraph | str | PathLike[str] | None = None,
        goals: str | int | Sequence[str | int] = "Dreese Lab",
        max_steps: int | str = "auto",
        **env_kwargs: Any,
    ) -> None:
        if world is None:
            n_intersections = DEFAULT_CITY_INTERSECTIONS if n_intersections is None else n_intersections
            world = generate_city(n_intersections, seed=DEFAULT_MAP_SEED if map_seed is None else map_seed)
        elif n_intersections is not None or map_seed is not None:
            raise ValueError(
                "CampusNavCity: world= takes a map of its own, so n_intersections and map_seed (which generate a city) "
                "must not be given with it"
            )
        elif not isinstance(world, (RoadGraph, NavigationGraph, PathLike)) and (
            not isinstance(world, str) or world == "campus"
        ):
            raise TypeError(
                "CampusNavCity: world must be a RoadGraph, a NavigationGraph or a GraphML file's path, got "
                f"{type(world).__name__} {world!r}"
            )
        super().__init__(world=world, goals=goals, max_steps=max_steps, **env_kwargs)
