"""Specification of the world cache (campusnav_env.features.world_cache): a big map's 3D world is placed once and read
back afterwards (a resumed view build, barrier views), never another map's or seed's, and a bad file costs a rebuild,
never an error or a wrong world."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from campusnav_env.features import view_source, world_cache
from campusnav_env.features.encoders import PixelProjectionEncoder
from campusnav_env.features.view_source import ViewSource
from campusnav_env.features.world_cache import cached_world, world_cache_path
from campusnav_env.maps.campus import generate_city
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.rendering.world import build_world

SMALL = 12  # intersections of the test maps; the cache threshold is lowered to it


@pytest.fixture
def cache_from_small_maps(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(world_cache, "MIN_NODES_FOR_WORLD_CACHE", SMALL)
    monkeypatch.setattr(view_source, "MIN_NODES_FOR_WORLD_CACHE", SMALL)


def no_placement(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the world was placed again")

    monkeypatch.setattr(world_cache, "build_world", refuse)


def test_a_small_map_places_its_world_and_keeps_no_file(tmp_path: Path) -> None:
    graph = generate_city(SMALL, seed=1)
    world = cached_world(graph, 0, tmp_path)
    assert world.fingerprint() == build_world(graph, seed=0).fingerprint()
    assert not list(tmp_path.iterdir())


@pytest.mark.usefixtures("cache_from_small_maps")
def test_a_big_map_places_its_world_once_and_reads_it_back(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    graph = generate_city(SMALL, seed=1)
    placed = cached_world(graph, 0, tmp_path)
    assert world_cache_path(graph, 0, tmp_path).is_file()
    no_placement(monkeypatch)
    read = cached_world(graph, 0, tmp_path)
    assert read.fingerprint() == placed.fingerprint() == build_world(graph, seed=0).fingerprint()


@pytest.mark.usefixtures("cache_from_small_maps")
def test_each_map_and_seed_has_its_own_file(tmp_path: Path) -> None:
    graph, other = generate_city(SMALL, seed=1), generate_city(SMALL, seed=2)
    paths = {
        world_cache_path(graph, 0, tmp_path),
        world_cache_path(graph, 1, tmp_path),
        world_cache_path(other, 0, tmp_path),
    }
    assert len(paths) == 3
    assert cached_world(graph, 1, tmp_path).seed == 1
    assert cached_world(other, 0, tmp_path).graph.fingerprint() == other.fingerprint()


@pytest.mark.usefixtures("cache_from_small_maps")
def test_a_torn_file_is_placed_again_and_replaced(tmp_path: Path) -> None:
    graph = generate_city(SMALL, seed=1)
    path = world_cache_path(graph, 0, tmp_path)
    path.write_bytes(b"\x80\x05 half a pickle")
    with pytest.warns(UserWarning, match="could not be read"):
        world = cached_world(graph, 0, tmp_path)
    assert world.fingerprint() == build_world(graph, seed=0).fingerprint()
    assert cached_world(graph, 0, tmp_path).fingerprint() == world.fingerprint()  # the file was replaced


@pytest.mark.usefixtures("cache_from_small_maps")
def test_a_file_holding_another_maps_world_is_never_used(tmp_path: Path) -> None:
    graph, other = generate_city(SMALL, seed=1), generate_city(SMALL, seed=2)
    cached_world(other, 0, tmp_path)
    world_cache_path(other, 0, tmp_path).rename(world_cache_path(graph, 0, tmp_path))
    with pytest.warns(UserWarning, match="another map's world"):
        world = cached_world(graph, 0, tmp_path)
    assert world.graph.fingerprint() == graph.fingerprint()


@pytest.mark.usefixtures("cache_from_small_maps")
def test_a_folder_that_cannot_be_written_costs_only_the_file(tmp_path: Path) -> None:
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the cache folder should be")
    graph = generate_city(SMALL, seed=1)
    with pytest.warns(UserWarning, match="could not be kept"):
        world = cached_world(graph, 0, blocker / "cache")
    assert world.fingerprint() == build_world(graph, seed=0).fingerprint()


@pytest.mark.usefixtures("cache_from_small_maps")
def test_a_build_that_needs_its_world_again_reads_it_instead_of_placing_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A killed view build leaves the world behind; the resumed build (and barrier views) read it."""
    graph = generate_city(SMALL, seed=1)

    def source() -> ViewSource:
        return ViewSource(
            graph,
            "features",
            PixelProjectionEncoder(dim=8),
            None,
            RenderSettings(32, 24),
            0,
            tmp_path,
            False,
            workers=1,
        )

    first = source().open_views()
    for views in tmp_path.glob("views-*.npz"):  # as if the build had been killed before its views were stored
        views.unlink()
    no_placement(monkeypatch)
    np.testing.assert_allclose(source().open_views(), first, atol=1e-6)
    assert source().renders_with(0, frozenset()).shape == (1, *first.shape[1:])
