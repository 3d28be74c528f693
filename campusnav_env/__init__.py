"""CampusNav: a Gymnasium environment for navigation and dynamic routing in changing road maps.

The pipeline, one subpackage per stage: :mod:`campusnav_env.maps` (road graphs, compass slots, closures) ->
:mod:`campusnav_env.rendering` (the 3D world, street views, map pictures) -> :mod:`campusnav_env.features` (CNN
encoders, projection, on-disk cache) -> :class:`CampusNavEnv` and :func:`evaluate_routes` here.

Importing the package registers ``CampusNav-v0`` (single goal, Dreese Lab), ``CampusNavMulti-v0`` (the four goals
of the paper), ``CampusNavGoal-v0`` (any intersection as the goal) and ``CampusNavCity-v0`` (a generated city of
1,000 intersections, :class:`CampusNavCityEnv`) with Gymnasium. Every one takes ``view_build`` (:class:`ViewBuild`: how
the views are built and cached) and ``view_variation`` (:class:`ViewVariation`: pictures that vary between visits);
:class:`GaussianObservationNoise` adds fresh noise to any env's observations.
"""

from campusnav_env.city_env import CampusNavCityEnv
from campusnav_env.env import CampusNavEnv
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.maps.campus import GOALS, default_campus, generate_campus, generate_city
from campusnav_env.maps.compass import ACTION_NAMES, BACK, COMPASS, FORWARD, LEFT, RIGHT
from campusnav_env.maps.navigation import NavigationGraph, RoadClosureError
from campusnav_env.maps.road_graph import RoadGraph, road_key
from campusnav_env.optimal_values import optimal_q_values
from campusnav_env.registration import register_envs
from campusnav_env.rendering.variation import ViewVariation
from campusnav_env.route_evaluation import Route, RouteReport, evaluate_routes
from campusnav_env.wrappers import GaussianObservationNoise

register_envs()

__all__ = [
    "ACTION_NAMES",
    "BACK",
    "COMPASS",
    "FORWARD",
    "GOALS",
    "LEFT",
    "RIGHT",
    "CampusNavCityEnv",
    "CampusNavEnv",
    "GaussianObservationNoise",
    "NavigationGraph",
    "RoadClosureError",
    "RoadGraph",
    "Route",
    "RouteReport",
    "ViewBuild",
    "ViewVariation",
    "default_campus",
    "evaluate_routes",
    "generate_campus",
    "generate_city",
    "optimal_q_values",
    "register_envs",
    "road_key",
]
