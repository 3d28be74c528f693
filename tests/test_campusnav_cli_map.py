"""``dcqn-campusnav`` on a map of one's own (``--map FILE.graphml``), routes as text, and what ``--help`` lists.

A small GraphML road network (a 5 x 5 grid of streets, 100 m apart, with two named nodes) trains with ``train --map``
and ``--goals``; the map's path goes into the model's ``.env.json``, so that ``evaluate`` and ``draw`` rebuild the
same env, and both print the pictured route as text (its nodes and the turn at each) and write it beside the picture.
A file that is no road network, and goals the map does not have, are refused naming the file. ``--help`` lists every
registered CampusNav id; ``roads`` takes only the options it uses. Cheap ``pixels`` views, 64 x 48.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import networkx as nx
import numpy as np
import pytest

from campusnav_env import figures
from campusnav_env.figures import training_curves
from campusnav_env.maps.compass import ACTION_NAMES
from sb3_dcqn.campusnav.cli import CommandError, build_parser, campusnav_env_ids, run
from sb3_dcqn.campusnav.settings import EnvSettings, load_map

FAST = ("--encoder", "pixels", "--render-size", "64", "48")
TINY_CONF = """\
CampusNav-v0:
  n_timesteps: 300
  policy: 'MultiInputPolicy'
  env_kwargs:
    view_dim: 16
    max_steps: 30
  buffer_size: 2000
  learning_starts: 100
  batch_size: 32
  train_freq: 4
  target_update_interval: 100
  policy_kwargs: "dict(features_extractor_class=EmbeddingFusionExtractor, features_extractor_kwargs=dict(embed_dim=16, \
features_dim=16), share_features_extractor=True, net_arch=[16], heading_key='heading')"
"""


# The session's feature cache: the views are rendered and encoded once, not once per test or module (conftest.py)
pytestmark = pytest.mark.usefixtures("shared_feature_cache")


@pytest.fixture(scope="module")
def grid_map(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """
    A 5 x 5 street grid in metres (node k at column k % 5, row k // 5), with a library (a corner) and a cinema (the
    centre); simplified to intersections, the three unnamed corners (each a bend between two roads) go.
    """
    graph = nx.Graph()
    for k in range(25):
        graph.add_node(str(k), x=100.0 * (k % 5), y=100.0 * (k // 5))
    for k in range(25):
        if k % 5 < 4:
            graph.add_edge(str(k), str(k + 1))
        if k < 20:
            graph.add_edge(str(k), str(k + 5))
    graph.nodes["24"]["name"] = "Library"
    graph.nodes["12"]["name"] = "Cinema"
    path = tmp_path_factory.mktemp("maps") / "grid.graphml"
    nx.write_graphml(graph, path)
    return path


@pytest.fixture
def tiny_conf(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.yml"
    path.write_text(TINY_CONF)
    return path


def cli(*argv: str) -> dict:
    return run(build_parser().parse_args(list(argv)))


def test_train_on_a_graphml_map_and_evaluate_and_draw_it_with_the_route_as_text(
    tmp_path: Path,
    grid_map: Path,
    tiny_conf: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    notes = []

    def curves(*args: Any, **kwargs: Any) -> np.ndarray:
        notes.append(kwargs.get("note"))
        return training_curves(*args, **kwargs)

    monkeypatch.setattr(figures, "training_curves", curves)
    out = tmp_path / "grid"
    summary = cli(
        "train", "--map", str(grid_map), "--goals", "Library", "--conf", str(tiny_conf), *FAST, "--no-progress",
        *("--timesteps", "300", "--eval-freq", "300", "--out", str(out)),
    )  # fmt: skip
    assert summary["settings"]["map"] == str(grid_map.resolve())
    assert summary["settings"]["env_kwargs"]["goals"] == ["Library"]
    graph = load_map(str(grid_map))
    assert graph.n_nodes == 22 and sorted(graph.landmarks) == ["Cinema", "Library"]
    assert summary["trained"]["n_routes"] == 21 * 4  # every other intersection, every heading
    assert "CampusNav-v0 on grid.graphml" in capsys.readouterr().out
    assert notes == [None]  # no start curriculum: every episode starts anywhere, as the route evaluations do
    saved = EnvSettings.from_json(summary["settings"])
    assert saved.map_path == str(grid_map.resolve()) and load_map(saved.map_path) is graph  # read once

    # evaluate takes the map from the model's .env.json, and writes the pictured route as text beside the picture
    picture = tmp_path / "route.png"
    scores = cli("evaluate", str(out / "dcqn_campusnav.zip"), "--start", "0", "--heading", "0", "--picture",
                 str(picture))  # fmt: skip
    printed = capsys.readouterr().out
    assert scores["all"]["n_routes"] == 21 * 4 and "grid.graphml" in printed
    route = scores["route"]
    assert route["start"] == 0 and route["heading"] == 0 and route["nodes"][0] == 0
    assert len(route["turns"]) == len(route["nodes"]) - 1 and set(route["turns"]) <= {*ACTION_NAMES, "blocked"}
    text = Path(route["text"]).read_text()
    assert Path(route["text"]) == tmp_path / "route.txt" and text in printed
    lines = text.splitlines()
    assert lines[0].startswith("route from node 0 facing N to Library: ")
    assert lines[1] == "nodes: " + " ".join(map(str, route["nodes"]))
    assert [line.split(": ")[1].split(" -> ")[0] for line in lines[2:]] == route["turns"]

    # draw: the same, and without a model the shortest path's nodes
    drawn = cli("draw", "--model", str(out / "dcqn_campusnav.zip"), "--start", "0", "--picture", str(picture))
    assert drawn["route"]["nodes"][0] == 0 and (tmp_path / "route.txt").is_file()
    capsys.readouterr()
    plain = cli("draw", "--map", str(grid_map), "--env", "CampusNav-v0", "--goal", "Library", "--start", "0", *FAST,
                "--picture", str(tmp_path / "map.png"))  # fmt: skip
    assert plain["route"] is None
    assert "shortest path from node 0 to Library: 0 " in capsys.readouterr().out


def test_a_map_that_is_no_road_network_or_lacks_the_goals_is_refused_naming_the_file(
    tmp_path: Path, grid_map: Path
) -> None:
    broken = tmp_path / "broken.graphml"
    broken.write_text("<graphml><graph>")  # cut off
    with pytest.raises(CommandError, match=rf"--map {broken}: not a GraphML road network"):
        cli("train", "--map", str(broken), *FAST, "--out", str(tmp_path / "out"))
    no_coordinates = tmp_path / "abstract.graphml"
    nx.write_graphml(nx.path_graph(4), no_coordinates)
    with pytest.raises(CommandError, match=rf"--map {no_coordinates}: not a GraphML road network \(.*x"):
        cli("train", "--map", str(no_coordinates), *FAST, "--out", str(tmp_path / "out"))
    with pytest.raises(CommandError, match=rf"--map {tmp_path / 'missing.graphml'}: file not found"):
        cli("train", "--map", str(tmp_path / "missing.graphml"), *FAST, "--out", str(tmp_path / "out"))
    # CampusNav-v0's goal is Dreese Lab, which this map does not have
    message = (
        rf"--map {grid_map}: goal 'Dreese Lab' \(the default of CampusNav-v0\) is not a landmark of the map "
        r"\(its named nodes: Cinema, Library\); pass --goals with landmark names or node ids 0..21"
    )
    with pytest.raises(CommandError, match=message):
        cli("train", "--map", str(grid_map), *FAST, "--out", str(tmp_path / "out"))
    with pytest.raises(CommandError, match=r"goal node 99 \(--goals\) is not on the map"):
        cli("demo", "--map", str(grid_map), "--goals", "99", *FAST, "--out", str(tmp_path / "out"))
    with pytest.raises(CommandError, match=r"env_kwargs of CampusNavCity-v0 already choose a map \(n_intersections\)"):
        conf = tmp_path / "city.yml"
        conf.write_text("CampusNavCity-v0:\n  n_timesteps: 10\n  policy: 'MultiInputPolicy'\n  env_kwargs:\n"
                        "    n_intersections: 60\n")  # fmt: skip
        cli("train", "--env", "CampusNavCity-v0", "--conf", str(conf), "--map", str(grid_map), "--goals", "Library",
            *FAST, "--out", str(tmp_path / "out"))  # fmt: skip
    assert not (tmp_path / "out").exists()  # refused before anything is trained or written


def test_help_lists_every_registered_campusnav_id(capsys: pytest.CaptureFixture[str]) -> None:
    import gymnasium as gym

    import campusnav_env  # noqa: F401  (registers the ids)

    registered = [i for i, spec in gym.registry.items() if str(spec.entry_point).startswith("campusnav_env.")]
    assert campusnav_env_ids() == registered and {"CampusNavCity-v0", "CampusNavCity10k-v0"} <= set(registered)
    for argv in ([], ["train"], ["evaluate"], ["roads"]):
        with pytest.raises(SystemExit):
            build_parser().parse_args([*argv, "--help"])
        text = " ".join(capsys.readouterr().out.split())  # argparse wraps the help
        assert all(env_id in text for env_id in registered), argv


def test_roads_takes_only_the_options_it_uses(grid_map: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        build_parser().parse_args(["roads", "--help"])
    text = capsys.readouterr().out
    assert "--env" in text and "--conf" in text and "--map" in text and "--close" in text
    for unused in ("--encoder", "--threads", "--render-size", "--encoder-weights", "--verbose"):
        assert unused not in text, unused
    with pytest.raises(SystemExit):
        build_parser().parse_args(["roads", "12", "--encoder", "pixels"])
    capsys.readouterr()
    cinema = load_map(str(grid_map)).landmarks["Cinema"]
    listed = cli("roads", str(cinema), "--map", str(grid_map), "--env", "CampusNav-v0")
    assert sorted(road["direction"] for road in listed["roads"]) == ["E", "N", "S", "W"]  # the grid's centre
    assert f"roads of node {cinema} (Cinema)" in capsys.readouterr().out


def ten_intersections(path: Path, crs: str | None = None) -> Path:
    """Ten nodes over 90 m x 80 m, x/y in metres (values that would also fit degrees), a library at node 9."""
    points = [(0, 0), (30, 0), (60, 0), (90, 0), (0, 40), (30, 40), (60, 40), (90, 40), (30, 80), (60, 80)]
    graph = nx.Graph()
    for node, (x, y) in enumerate(points):
        graph.add_node(node, x=float(x), y=float(y))
    graph.nodes[9]["name"] = "Library"
    graph.add_edges_from([(0, 1), (1, 2), (2, 3), (0, 4), (1, 5), (2, 6), (3, 7), (4, 5), (5, 6), (6, 7), (5, 8),
                          (6, 9), (8, 9)])  # fmt: skip
    if crs is not None:
        graph.graph["crs"] = crs
    nx.write_graphml(graph, path)
    return path


def test_a_ten_intersection_map_in_metres_draws_and_trains_with_the_shipped_view_dim(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    town = ten_intersections(tmp_path / "town.graphml")
    # The shipped entry's view_dim 64 is more than 40 views span: fitted, said once; no crs: read as metres, said
    with pytest.warns(UserWarning) as said:
        summary = cli("train", "--map", str(town), "--goals", "Library", *FAST, "--no-progress",
                      *("--timesteps", "200", "--eval-freq", "200", "--out", str(tmp_path / "run")))  # fmt: skip
    assert any("using view_dim" in str(w.message) for w in said)
    assert "x/y read as metres" in capsys.readouterr().err
    nodes = load_map(str(town)).n_nodes  # bends simplified away
    assert summary["trained"]["n_routes"] == 4 * (nodes - 1) and summary["settings"]["map_coords"] == "auto"
    drawn = cli("draw", "--model", str(tmp_path / "run" / "dcqn_campusnav.zip"), "--start", "0",
                "--picture", str(tmp_path / "town.png"))  # fmt: skip
    assert drawn["route"]["nodes"][0] == 0 and (tmp_path / "town.png").is_file()


def test_coordinates_come_from_the_crs_or_the_flag_and_a_map_that_cannot_be_built_is_refused_first(
    tmp_path: Path,
) -> None:
    # A crs that says degrees makes 11,000 km roads of these metres: refused before any view, with the flag to fix it
    claimed = ten_intersections(tmp_path / "claimed.graphml", crs="EPSG:4326")
    message = rf"--map {claimed}: too large to build its street views: .* load the map with --map-coords projected"
    with pytest.raises(CommandError, match=message):
        cli("draw", "--map", str(claimed), "--goal", "Library", *FAST, "--picture", str(tmp_path / "x.png"))
    assert not (tmp_path / "x.png").exists()
    drawn = cli("draw", "--map", str(claimed), "--map-coords", "projected", "--goal", "Library", *FAST,
                "--picture", str(tmp_path / "x.png"))  # fmt: skip
    assert drawn["picture"] and (tmp_path / "x.png").is_file()
    with pytest.raises(CommandError, match=r"--map-coords: .* give --map FILE\.graphml too"):
        cli("draw", "--map-coords", "projected", *FAST, "--picture", str(tmp_path / "y.png"))
