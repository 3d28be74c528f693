"""Scene files in Zhu et al.'s HDF5 format load as a CampusNav environment."""

from __future__ import annotations

import json
from collections import deque
from pathlib import Path

import numpy as np
import pytest

h5py = pytest.importorskip("h5py")

from campusnav_env.env import CampusNavEnv  # noqa: E402
from campusnav_env.maps.navigation import NavigationGraph  # noqa: E402
from campusnav_env.maps.scene_file import load_scene_file  # noqa: E402

# AI2-THOR-style actions: 0 forward, 1 backward, 2 turn left, 3 turn right; rotations 0/90/180/270 degrees
STEP = {0: (0, 1), 90: (1, 0), 180: (0, -1), 270: (-1, 0)}


def write_grid_scene(path: Path, size: int = 3, *, images: bool = True, landmarks: dict | None = None) -> int:
    """A size x size grid of locations, 4 rotations each, in the dump format; returns the number of states."""
    states = [(x, y, r) for x in range(size) for y in range(size) for r in (0, 90, 180, 270)]
    index = {s: i for i, s in enumerate(states)}
    graph = np.full((len(states), 4), -1, dtype=np.int64)
    for (x, y, r), i in index.items():
        dx, dy = STEP[r]
        graph[i, 0] = index.get((x + dx, y + dy, r), -1)
        graph[i, 1] = index.get((x - dx, y - dy, r), -1)
        graph[i, 2] = index[(x, y, (r - 90) % 360)]
        graph[i, 3] = index[(x, y, (r + 90) % 360)]
    distances = np.array([_bfs(graph, i) for i in range(len(states))])
    rng = np.random.default_rng(0)
    with h5py.File(path, "w") as file:
        file["graph"] = graph
        file["location"] = np.array([(x, y) for x, y, _ in states], dtype=np.float32)
        file["rotation"] = np.array([r for _, _, r in states], dtype=np.int64)
        file["resnet_feature"] = rng.normal(size=(len(states), 32, 3)).astype(np.float32)
        file["shortest_path_distance"] = distances
        if images:
            file["observation"] = rng.integers(0, 256, size=(len(states), 30, 40, 3), dtype=np.uint8)
        if landmarks:
            file.attrs["landmarks"] = json.dumps(landmarks)
    return len(states)


def _bfs(graph: np.ndarray, start: int) -> np.ndarray:
    hops = np.full(graph.shape[0], -1)
    hops[start] = 0
    queue = deque([start])
    while queue:
        s = queue.popleft()
        for t in graph[s]:
            if t >= 0 and hops[t] < 0:
                hops[t] = hops[s] + 1
                queue.append(t)
    return hops


def test_loads_states_as_locations_with_compass_views(tmp_path: Path) -> None:
    path = tmp_path / "grid.h5"
    n_states = write_grid_scene(path)
    scene = load_scene_file(path)
    assert scene.graph.n_states == n_states and scene.graph.n_nodes == 9
    assert scene.node_features.shape == (9, 4, 32)  # 3 crops averaged
    assert scene.node_images.shape == (9, 4, 30, 40, 3)  # the file's images, per location and compass slot
    assert len(scene.graph.roads) == 12  # a 3 x 3 grid has 12 edges


def test_hops_agree_with_the_files_shortest_path_distance(tmp_path: Path) -> None:
    path = tmp_path / "grid.h5"
    write_grid_scene(path)
    scene = load_scene_file(path)
    with h5py.File(path) as file:
        distances = file["shortest_path_distance"][()]
    goal = 8
    goal_states = np.flatnonzero(scene.graph.state_nodes == goal)
    per_state = distances[:, goal_states].min(axis=1)
    expected = np.array([per_state[scene.graph.state_nodes == n].min() for n in range(9)])
    np.testing.assert_array_equal(NavigationGraph(scene.graph).hops_to(goal), expected)


def test_runs_as_an_environment_with_goals_by_name_and_closures(tmp_path: Path) -> None:
    path = tmp_path / "grid.h5"
    write_grid_scene(path, landmarks={"Kitchen": 8})
    env = CampusNavEnv.from_scene_file(path, goals="Kitchen")
    obs, info = env.reset(seed=0)
    assert obs["views"].shape == (4 * 32,) and info["goal"] == "Kitchen"
    total_steps = 0
    while True:
        mask = info["action_mask"]
        _, _, terminated, truncated, info = env.step(int(np.flatnonzero(mask)[0]))
        total_steps += 1
        if terminated or truncated:
            break
    assert total_steps <= env.max_steps
    distances = env.node_distances(8).copy()
    env.close_road(7, 8)
    assert env.node_distances(8)[7] > distances[7]
    env.reopen_road(7, 8)
    np.testing.assert_array_equal(env.node_distances(8), distances)
    image_env = CampusNavEnv.from_scene_file(path, goals=[8], observation_mode="image", render_mode="rgb_array")
    assert image_env.reset(seed=0)[0].shape == (3, 96, 256)
    picture = image_env.render()
    assert picture.ndim == 3 and picture.dtype == np.uint8


def test_a_scene_file_env_renders_after_moves_and_closures(tmp_path: Path) -> None:
    path = tmp_path / "grid.h5"
    write_grid_scene(path)
    env = CampusNavEnv.from_scene_file(path, goals=[8], render_mode="rgb_array")
    _, info = env.reset(seed=0, options={"start": 0, "heading": 0})
    first = env.render()
    _, _, _, _, info = env.step(0)  # forward, north: a move to another location
    assert info["node"] != 0 and not info["collision"]
    moved = env.render()  # the route so far follows the scene's roads
    assert moved.shape == first.shape and not np.array_equal(moved, first)
    env.close_road(0, info["node"])
    closed = env.render()  # the closed road is drawn
    assert not np.array_equal(closed, moved)


def test_bad_scene_files_give_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"missing\.h5"):
        load_scene_file(tmp_path / "missing.h5")
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(b"not an hdf5 file")
    with pytest.raises(ValueError, match=r"garbage\.h5"):
        load_scene_file(garbage)
    partial = tmp_path / "partial.h5"
    with h5py.File(partial, "w") as file:
        file["graph"] = np.zeros((2, 4), dtype=np.int64)
    with pytest.raises(KeyError, match="resnet_feature"):
        load_scene_file(partial)
    no_images = tmp_path / "no_images.h5"
    write_grid_scene(no_images, images=False)
    with pytest.raises(ValueError, match="observation"):
        CampusNavEnv.from_scene_file(no_images, goals=[0], observation_mode="image")
    broken = tmp_path / "broken.h5"
    write_grid_scene(broken)
    with h5py.File(broken, "r+") as file:
        file["graph"][0, 0] = 999
    with pytest.raises(ValueError, match="row 0"):
        load_scene_file(broken)
