"""The ``dcqn-campusnav`` command line, in process, on small fast configurations.

Every subcommand runs end to end on the built-in campus with the cheap ``pixels`` encoder on 64 x 48 views (from the
session's feature cache) and a few hundred steps: ``demo`` (also as the command without a subcommand),
``train`` with a schedule file and with closure flags, ``readapt``, ``evaluate``, ``draw`` and ``roads``; bad input
gives errors that name the flag, file or road (the rough edges a new user met: tests/test_campusnav_cli_errors.py).
The shipped hyperparameter file's entry is checked here too.
"""

from __future__ import annotations

import json
import re
import zipfile
from pathlib import Path

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sb3_dcqn import DCQN
from sb3_dcqn.campusnav.cli import CommandError, build_parser, main, run
from sb3_dcqn.fusion import EmbeddingFusionExtractor
from sb3_dcqn.replay import RevisionDictReplayBuffer
from sb3_dcqn.zoo_entry import EntryError, load_zoo_entry
from sb3_dcqn.zoo_files import default_hyperparams_path

FAST = ("--encoder", "pixels", "--render-size", "64", "48")
# A small CampusNav entry: short episodes, a small buffer (saved with the model) and small networks
TINY_CONF = """\
CampusNav-v0:
  n_timesteps: 400
  policy: 'MultiInputPolicy'
  env_kwargs:
    view_dim: 16
    max_steps: 40
  learning_rate: !!float 1e-3
  buffer_size: 2000
  learning_starts: 100
  batch_size: 32
  train_freq: 4
  target_update_interval: 100
  exploration_fraction: 0.5
  policy_kwargs: "dict(features_extractor_class=EmbeddingFusionExtractor, features_extractor_kwargs=dict(embed_dim=16, \
features_dim=16), share_features_extractor=True, net_arch=[16], heading_key='heading')"
"""
ROAD = ("14", "15")  # a road of the built-in campus whose closure keeps every goal reachable


# The session's feature cache: the views are rendered and encoded once, not once per test or module (conftest.py)
pytestmark = pytest.mark.usefixtures("shared_feature_cache")


@pytest.fixture
def tiny_conf(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.yml"
    path.write_text(TINY_CONF)
    return path


def write_model_lookalike(path: Path) -> None:
    """A zip with the entry a saved model has: it passes the command line's first look at a model file."""
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("data", "{}")


def cli(*argv: str) -> dict:
    return run(build_parser().parse_args(list(argv)))


def tensorboard_tags(folder: Path) -> dict[str, set[str]]:
    events = EventAccumulator(str(folder))
    events.Reload()
    tags = events.Tags()
    return {"scalars": set(tags["scalars"]), "images": set(tags["images"])}


# ------------------------------------------------------------------------------------------------ zoo entry
def test_campusnav_entry_uses_the_fusion_extractor() -> None:
    entry = load_zoo_entry(default_hyperparams_path(), "CampusNav-v0")
    assert entry.n_timesteps > 0 and entry.hyperparams["policy"] == "MultiInputPolicy"
    assert entry.hyperparams["policy_kwargs"]["features_extractor_class"] is EmbeddingFusionExtractor
    assert entry.env_kwargs == {"view_dim": 64}


def test_job_reports_bad_hyperparameter_files_clearly(tmp_path: Path) -> None:
    with pytest.raises(EntryError, match=r"nope\.yml"):
        load_zoo_entry(tmp_path / "nope.yml", "CampusNav-v0")
    conf = tmp_path / "conf.yml"
    conf.write_text("CartPole-v1:\n  policy: MlpPolicy\n")
    with pytest.raises(EntryError, match="CampusNav-v0"):
        load_zoo_entry(conf, "CampusNav-v0")
    with pytest.raises(EntryError, match="n_timesteps"):
        load_zoo_entry(conf, "CartPole-v1")
    conf.write_text("CartPole-v1:\n  n_timesteps: 10\n  policy_kwargs: 'dict(net_arch=[64'\n")
    with pytest.raises(EntryError, match="policy_kwargs"):
        load_zoo_entry(conf, "CartPole-v1")


# ------------------------------------------------------------------------------------------------ demo
def test_demo_is_the_default_and_closes_the_busiest_road_twice(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert build_parser().parse_args([]).command == "demo"
    out = tmp_path / "run"
    # Options without a subcommand: demo, with the shipped CampusNav-v0 entry
    main([*FAST, "--timesteps", "600", "--recovery-budget", "300", "--eval-freq", "300", "--out", str(out)])
    printed = capsys.readouterr()
    assert "| phase | env step |" in printed.out and "| trained |" in printed.out
    assert "| closure | roads |" in printed.out and "| **median** |" in printed.out
    assert str(out / "routes.png") in printed.out and str(out / "summary.json") in printed.out
    assert "train:" in printed.err and "step" in printed.err  # the progress bar
    for name in ("routes.png", "curves.png", "dcqn_campusnav.zip", "dcqn_campusnav.env.json"):
        assert (out / name).is_file(), name
    assert not (out / "dcqn_campusnav_replay_buffer.pkl").exists()  # demo keeps no replay buffer
    summary = json.loads((out / "summary.json").read_text())
    assert summary["command"] == "demo" and summary["settings"]["env_kwargs"] == {"view_dim": 64}
    assert summary["levers"] == ["revision", "blocked"]  # the demo re-adapts with its fastest levers
    assert summary["trained"]["step"] == summary["closures"][0]["right_after"]["step"]
    assert len(summary["closures"]) == 2 and all(len(c["closed"]) == 1 for c in summary["closures"])
    assert summary["closures"][0]["closed"] != summary["closures"][1]["closed"]
    assert "| closure | roads |" in (out / "summary.md").read_text()
    tags = tensorboard_tags(out / "tb" / "DCQN_1")
    assert {"eval/success_rate", "eval/spl", "closure/events", "closure/closed_roads"} <= tags["scalars"]
    assert {"figures/routes", "figures/curves"} <= tags["images"]


# ------------------------------------------------------------------------------------------------ train, readapt, ...
def test_train_readapt_evaluate_and_draw(tmp_path: Path, tiny_conf: Path, capsys: pytest.CaptureFixture[str]) -> None:
    schedule = tmp_path / "schedule.yml"
    schedule.write_text(
        f"closures:\n  - {{at: 150, unit: step, close: [[{ROAD[0]}, {ROAD[1]}]]}}\n"
        "  - {at: 300, unit: step, close_on_route: busiest}\n"
    )
    out = tmp_path / "train"
    summary = cli(
        "train", *FAST, "--conf", str(tiny_conf), "--closures", str(schedule), "--keep-training",
        *("--timesteps", "450", "--eval-freq", "150", "--out", str(out), "--no-progress"),
    )  # fmt: skip
    printed = capsys.readouterr().out
    assert "| closure | roads |" in printed and f"{ROAD[0]}-{ROAD[1]}" in printed
    assert summary["num_timesteps"] >= 450 and len(summary["closures"]) == 2
    assert summary["closures"][0]["closed"] == [[int(ROAD[0]), int(ROAD[1])]]
    model = out / "dcqn_campusnav.zip"
    assert (out / "dcqn_campusnav_replay_buffer.pkl").is_file()
    assert json.loads((out / "dcqn_campusnav.env.json").read_text())["settings"]["env_kwargs"]["view_dim"] == 16
    scalars = tensorboard_tags(out / "tb" / "DCQN_1")["scalars"]
    assert {"closure/events", "closure/routes_affected", "eval/success_rate", "train/critic_1_loss"} <= scalars

    # readapt: the env and the replay buffer come with the model; the input is kept
    before = model.read_bytes()
    readapted = cli("readapt", str(model), "--close-random", "2", "--timesteps", "200", "--no-progress")
    printed = capsys.readouterr()
    assert "| closure | roads |" in printed.out and "replay buffer:" in printed.err
    # readapt trains no model to solved: it reports how the loaded model's routes stood before the first closure
    assert "not solved before the first closure" not in printed.out
    assert re.search(r"the model before the first closure \(step \d+\): success \d\.\d{3}, SPL \d\.\d{3}", printed.out)
    assert readapted["num_timesteps"] > 450 and len(readapted["closures"][0]["closed"]) == 2
    assert (out / "readapt" / "dcqn_campusnav.zip").is_file() and (out / "readapt" / "routes.png").is_file()
    assert model.read_bytes() == before
    cli("readapt", str(model), "--close-on-route", "busiest", "--timesteps", "100", "--in-place", "--no-progress")
    assert model.read_bytes() != before

    # evaluate under a closure of the open map, with a picture
    picture = tmp_path / "eval.png"
    scores = cli("evaluate", str(model), "--open-map", "--close", *ROAD, "--picture", str(picture))
    printed = capsys.readouterr().out
    assert "| all |" in printed and "| Dreese Lab |" in printed and f"roads closed: {ROAD[0]}-{ROAD[1]}" in printed
    assert picture.is_file() and scores["closed_roads"] == [[int(ROAD[0]), int(ROAD[1])]]
    assert set(scores["all"]) >= {"success_rate", "spl", "coverage", "mean_steps"}
    # without --open-map: the roads closed when the model was saved, which include ROAD (train's schedule closed it)
    at_save = json.loads((out / "dcqn_campusnav.env.json").read_text())["closed_roads_at_save"]
    # train's two closures, restored by the in-place readapt, which closed one more road (the busiest)
    assert [int(ROAD[0]), int(ROAD[1])] in at_save and len(at_save) == 3
    scores = cli("evaluate", str(model), "--close", *ROAD)  # closed already: a note, not an error
    printed = capsys.readouterr()
    assert sorted(scores["closed_roads"]) == sorted(at_save) == sorted(scores["restored_closures"])
    assert "closed again: " in printed.err and "closed already (saved with the model)" in printed.err

    # draw a model's route from a start, and the bare map
    drawn = cli("draw", "--model", str(model), "--start", "3", "--picture", str(tmp_path / "route.png"))
    assert (tmp_path / "route.png").is_file() and drawn["route"]["start"] == 3
    cli("draw", *FAST, "--close", *ROAD, "--node-ids", "--picture", str(tmp_path / "map.png"))
    assert (tmp_path / "map.png").is_file()

    # a model evaluated on other observations than it was trained on (64 dimensions per view, not 16)
    with pytest.raises(CommandError, match="do not match"):
        cli("evaluate", str(model), "--conf", str(default_hyperparams_path()))


def test_train_with_closure_flags_and_two_envs(tmp_path: Path, tiny_conf: Path) -> None:
    out = tmp_path / "flags"
    summary = cli(
        "train", *FAST, "--conf", str(tiny_conf), "--n-envs", "2", "--close", *ROAD, "--close-at", "200",
        *("--timesteps", "400", "--eval-freq", "200", "--no-replay-buffer", "--out", str(out), "--no-progress"),
        *("--levers", "revision", "blocked", "visible"),
    )  # fmt: skip
    # The levers reach DCQN and the env, and are saved with the model
    model = DCQN.load(out / "dcqn_campusnav.zip")
    assert model.replay_buffer_class is RevisionDictReplayBuffer and model.blocked_action_target
    assert summary["levers"] == ["revision", "blocked", "visible"]
    assert summary["settings"]["env_kwargs"]["visible_closures"] is True
    (closure,) = summary["closures"]
    assert closure["description"] == f"step 200: close {ROAD[0]}-{ROAD[1]}"
    assert not (out / "dcqn_campusnav_replay_buffer.pkl").exists()
    assert "closure/closed_roads" in tensorboard_tags(out / "tb" / "DCQN_1")["scalars"]


# ------------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["evaluate", "{tmp}/nope.zip"], r"model file not found: .*nope\.zip"),
        (["train", "--close", "1", "99"], r"--close: road 1-99: no road between nodes 1 and 99"),
        (["train", "--closures", "{tmp}/none.yml"], r"--closures: closure schedule not found: .*none\.yml"),
        (["train", "--closures", "{tmp}/none.yml", "--close", "1", "2"], "cannot be combined"),
        (["train", "--close-at", "100"], "--close-at: give the roads to close"),
        (["train", "--conf", "{tmp}/none.yml"], r"--conf: hyperparameter file not found: .*none\.yml"),
        (["train", "--env", "CartPole-v1"], "--env CartPole-v1: not a CampusNav env"),
        (["evaluate", "{tmp}/model.zip", "--env", "Nowhere-v0"], "--env Nowhere-v0: .*Nowhere"),
        (["train", "--close-on-route", "500"], "--close-on-route: .*500 out of range"),
        (["train", "--render-size", "8", "8"], "--render-size: width and height must be at least 16"),
        (["readapt", "{tmp}/model.zip"], "readapt: give the roads to close"),
        (["readapt", "{tmp}/model.zip", "--close", "1", "2", "--out", "{tmp}"], "would overwrite"),
        (["evaluate", "{tmp}/model.zip", "--close", "1", "99"], "--close 1 99: no road between nodes 1 and 99"),
        (["draw", "--start", "500", "--picture", "{tmp}/x.png"], "--start: start 500 out of range"),
        (["draw", "--goal", "Nowhere", "--picture", "{tmp}/x.png"], "--goal 'Nowhere': not a goal"),
        (["roads", "500"], "roads: node 500 out of range"),
        (["roads", "14", "--close", "1", "99"], "--close 1 99: no road between nodes 1 and 99"),
    ],
)
def test_bad_input_names_the_flag_file_or_road(tmp_path: Path, argv: list[str], message: str) -> None:
    write_model_lookalike(tmp_path / "model.zip")  # these errors come before the model is loaded
    argv = [arg.replace("{tmp}", str(tmp_path)) for arg in argv]
    if argv[0] == "train":
        argv += ["--out", str(tmp_path / "out")]
    with pytest.raises(CommandError, match=message):
        # the case's own flags come last, and win; roads takes no view flags (its answer does not depend on them)
        cli(argv[0], *(FAST if argv[0] != "roads" else ()), *argv[1:])


def test_main_prints_errors_and_exits_with_status_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["evaluate", str(tmp_path / "nope.zip")])
    assert exit_info.value.code == 2
    assert "dcqn-campusnav evaluate: error: model file not found" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "--close-on-route", "nowhere"])
    assert "expected 'busiest' or a start node id, got 'nowhere'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "--levers", "telepathy"])
    assert "--levers: invalid choice: 'telepathy'" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------ roads
def test_roads_lists_an_intersections_roads_with_directions_and_closures(capsys: pytest.CaptureFixture[str]) -> None:
    listed = cli("roads", ROAD[0], "--close", *ROAD)
    printed = capsys.readouterr().out
    roads = {tuple(road["road"]): road for road in listed["roads"]}
    # Node 14 of the built-in campus has three roads, in its N, E and S slots; the closed one says so
    assert set(roads) == {(14, 25), (14, 15), (14, 4)}
    assert [roads[(14, other)]["direction"] for other in (25, 15, 4)] == ["N", "E", "S"]
    assert roads[(14, 15)]["closed"] and not roads[(14, 25)]["closed"]
    assert "  14 15  E  closed" in printed and "  14 25  N  open" in printed
    assert "'--close U V' closes one" in printed
