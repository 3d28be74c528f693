"""ViewBuild: the env's view-building settings as one object, taken as it is (or from YAML) by every CampusNav env."""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest

from campusnav_env import CampusNavCityEnv, CampusNavEnv, ViewBuild
from campusnav_env.features.encoders import PixelProjectionEncoder
from campusnav_env.features.view_build import with_view_build
from campusnav_env.goal_env import CampusNavGoalEnv
from campusnav_env.maps.campus import generate_campus
from campusnav_env.rendering.street_view import RenderSettings

GRAPH = generate_campus(16, seed=1)
BUILD_FIELDS = {field.name for field in dataclasses.fields(ViewBuild)}


class CnnSizedEncoder(PixelProjectionEncoder):
    """A pixel encoder that declares a CNN's 224 x 224 input size."""

    view_input_size = (224, 224)


def test_campusnav_takes_at_most_14_arguments_and_the_other_envs_repeat_none_of_the_builds() -> None:
    parameters = inspect.signature(CampusNavEnv.__init__).parameters
    assert len(parameters) - 1 <= 14  # FrozenLake takes 6
    assert "view_build" in parameters and not BUILD_FIELDS & set(parameters)
    for env_class in (CampusNavGoalEnv, CampusNavCityEnv):
        own = set(inspect.signature(env_class.__init__).parameters)
        assert not BUILD_FIELDS & own, f"{env_class.__name__} restates {sorted(BUILD_FIELDS & own)}"


def test_a_yaml_mapping_makes_the_same_build_as_the_object(tmp_path: Path) -> None:
    yaml_like = {"render_settings": {"width": 64, "height": 48}, "cache_dir": str(tmp_path), "workers": 2}
    built = ViewBuild.of(yaml_like)
    assert built == ViewBuild(render_settings=RenderSettings(64, 48), cache_dir=str(tmp_path), workers=2)
    assert ViewBuild.of(None) == ViewBuild() and ViewBuild.of(built) is built
    assert ViewBuild.of(yaml_like, progress=False).progress is False  # changes over a YAML entry's build
    merged = with_view_build({"view_dim": 64, "view_build": yaml_like}, progress=False)
    assert merged["view_dim"] == 64 and merged["view_build"] == dataclasses.replace(built, progress=False)


def test_every_env_takes_the_build_and_uses_it(tmp_path: Path) -> None:
    build = {"render_settings": {"width": 64, "height": 48}, "cache_dir": str(tmp_path), "progress": False}
    for env_id in ("CampusNav-v0", "CampusNavGoal-v0", "CampusNavCity-v0"):
        env = gym.make(env_id, world=GRAPH, encoder="pixels", view_build=build).unwrapped
        assert env.view_build == ViewBuild.of(build), env_id
    assert len(list(tmp_path.glob("views-*.npz"))) == 1  # one map, one build: every env read the same cache entry


def test_views_fit_the_encoder_where_the_build_leaves_it_to_the_env() -> None:
    open_build = ViewBuild()
    as_campus = open_build.source(GRAPH, "features", CnnSizedEncoder(), fit_views_to_encoder=False)
    as_city = open_build.source(GRAPH, "features", CnnSizedEncoder(), fit_views_to_encoder=True)
    assert (as_campus.settings.width, as_campus.settings.height) == (640, 480)
    assert (as_city.settings.width, as_city.settings.height) == (299, 224)
    said = ViewBuild(fit_views_to_encoder=False).source(GRAPH, "features", CnnSizedEncoder(), fit_views_to_encoder=True)
    assert said.settings.width == 640  # the build's own word wins
    assert not CampusNavEnv.fits_views_to_encoder and CampusNavCityEnv.fits_views_to_encoder


@pytest.mark.parametrize(
    ("fields", "error", "match"),
    [
        ({"workers": 0}, ValueError, r"ViewBuild\.workers must be an int >= 1 or None, got 0"),
        ({"backend": "dask"}, ValueError, r"ViewBuild\.backend must be one of 'local', 'ray', got 'dask'"),
        ({"ray_address": "auto"}, ValueError, r"ViewBuild\.ray_address='auto' is for backend='ray'"),
        ({"progress": "no"}, TypeError, r"ViewBuild\.progress must be True or False, got 'no'"),
        ({"normalize_features": 1}, TypeError, r"ViewBuild\.normalize_features must be True or False"),
        ({"world_seed": 1.5}, TypeError, r"ViewBuild\.world_seed must be an int, got 1\.5"),
        ({"cache_dir": 3}, TypeError, r"ViewBuild\.cache_dir must be a path or None, got 3"),
        ({"encoder_kwargs": [1]}, TypeError, r"ViewBuild\.encoder_kwargs must be a mapping"),
        ({"render_settings": "small"}, TypeError, r"ViewBuild\.render_settings must be a RenderSettings or None"),
        ({"render_settings": {"size": 64}}, TypeError, r"render_settings: unknown field\(s\) \['size'\]"),
        ({"fit_views_to_encoder": "yes"}, TypeError, r"ViewBuild\.fit_views_to_encoder must be True, False or None"),
        ({"build_workers": 4}, TypeError, r"view_build: unknown field\(s\) \['build_workers'\]; the fields are"),
    ],
)
def test_bad_build_settings_name_the_field(fields: dict[str, Any], error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        ViewBuild.of(fields)


def test_an_env_refuses_a_build_of_another_type() -> None:
    with pytest.raises(TypeError, match="view_build must be a ViewBuild, a mapping of its fields or None, got str"):
        CampusNavEnv(world=GRAPH, encoder="pixels", view_build="fast")
