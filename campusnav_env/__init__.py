"""CampusNav: a Gymnasium environment for navigation and dynamic routing in changing road maps.

Importing the package registers ``CampusNav-v0`` (single goal, Dreese Lab) and ``CampusNavMulti-v0`` (the four goals
of the paper) with Gymnasium.
"""

from campusnav_env.env import CampusNavEnv
from campusnav_env.maps.campus import GOALS, default_campus, generate_campus
from campusnav_env.maps.road_graph import ACTION_NAMES, COMPASS, RoadClosureError, RoadGraph
from campusnav_env.registration import register_envs

register_envs()

__all__ = [
    "ACTION_NAMES",
    "COMPASS",
    "GOALS",
    "CampusNavEnv",
    "RoadClosureError",
    "RoadGraph",
    "default_campus",
    "generate_campus",
    "register_envs",
]
