"""CampusNavGoal's ``max_steps="auto"``: the cap follows the goals episodes draw, not every intersection a goal may be
asked for or relabelled to.

Envs use pixel features of small views. The 150-intersection city checks the rule in the default selection (against
the city env's own cap too); the 1,000-intersection one, whose cold view build takes 25-80 s on one core, is marked
slow.
"""

from __future__ import annotations

from typing import Any

import pytest

import campusnav_env.env as env_module
from campusnav_env import CampusNavCityEnv
from campusnav_env.env import auto_max_steps, longest_shortest_route
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.goal_env import CampusNavGoalEnv
from campusnav_env.maps.campus import generate_city
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.rendering.street_view import RenderSettings

SMALL_CITY = generate_city(150, seed=0)
LONGEST_TO_DREESE = 18  # hops from the farthest start to Dreese Lab on SMALL_CITY (as in test_city_env.py)


@pytest.fixture(scope="module")
def env_kwargs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return dict(
        encoder="pixels",
        view_build=ViewBuild(
            render_settings=RenderSettings(width=16, height=16),
            cache_dir=tmp_path_factory.mktemp("cache"),
            progress=False,
        ),
        view_dim=16,
    )


@pytest.mark.slow
def test_auto_cap_at_1000_intersections_is_the_city_envs_own(env_kwargs: dict[str, Any]) -> None:
    city = generate_city(1_000, seed=0)
    goal_env = CampusNavGoalEnv(world=city, goals=["Dreese Lab"], max_steps="auto", **env_kwargs)
    city_env = CampusNavCityEnv(world=city, goals="Dreese Lab", **env_kwargs)
    assert goal_env.max_steps == city_env.max_steps == 200
    # Every intersection is a goal the env may be asked for; its longest route would make the cap 240
    assert auto_max_steps(goal_env.graph, goal_env.goal_nodes) == 240


def test_auto_cap_follows_the_training_goals_not_the_held_out_ones(
    env_kwargs: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(env_module, "AUTO_MAX_STEPS_FLOOR", 1)  # the floor out of the way: the cap is 4 x the route
    graph = NavigationGraph(SMALL_CITY)
    dreese = graph.landmarks["Dreese Lab"]
    to_dreese = CampusNavGoalEnv(world=SMALL_CITY, goals=[dreese], max_steps="auto", **env_kwargs)
    assert to_dreese.max_steps == 4 * LONGEST_TO_DREESE
    assert CampusNavCityEnv(world=SMALL_CITY, goals="Dreese Lab", **env_kwargs).max_steps == to_dreese.max_steps
    # Every intersection drawn: the longest route between any two
    every = CampusNavGoalEnv(world=SMALL_CITY, max_steps="auto", **env_kwargs)
    diameter = longest_shortest_route(graph, list(range(graph.n_nodes)))
    assert diameter > LONGEST_TO_DREESE and every.max_steps == 4 * diameter
    # Held-out goals are never drawn: holding out the goals with a start that far away shortens the cap
    far_goals = [node for node in range(graph.n_nodes) if int(graph.hops_to(node).max()) == diameter]
    held = CampusNavGoalEnv(world=SMALL_CITY, held_out_goals=far_goals, max_steps="auto", **env_kwargs)
    training = [node for node in range(graph.n_nodes) if node not in far_goals]
    assert held.max_steps == 4 * longest_shortest_route(graph, training) < every.max_steps
    # An int still fixes the cap; a string other than "auto" is refused by name
    assert CampusNavGoalEnv(world=SMALL_CITY, goals=[dreese], max_steps=7, **env_kwargs).max_steps == 7
    with pytest.raises(ValueError, match="max_steps must be an int or 'auto', got 'longest'"):
        CampusNavGoalEnv(world=SMALL_CITY, goals=[dreese], max_steps="longest", **env_kwargs)
