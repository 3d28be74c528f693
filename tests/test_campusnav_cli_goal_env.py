"""``dcqn-campusnav`` on the goal-conditioned ``CampusNavGoal-v0``: any intersection the goal, hindsight relabelling.

The shipped entry trains as it is (``replay_buffer_class: HerReplayBuffer`` becomes SB3's class, served by DCQN's
HER buffer), its routes to all 101 goals are evaluated, a road on the learned routes closes and the recovery is
measured; models load with their env for ``evaluate``, ``readapt`` (with the HER buffer saved next to them) and
``draw``. Closures keep every intersection reachable. Prioritised replay, which cannot run with hindsight
relabelling, is refused by name; ``demo``'s default levers (revision, blocked) run as they are. Cheap ``pixels``
views, 64 x 48, from the session's feature cache.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from campusnav_env import GOALS
from sb3_dcqn import DCQN
from sb3_dcqn.campusnav.cli import CommandError, build_parser, run
from sb3_dcqn.campusnav.pictures import picture_goals
from sb3_dcqn.campusnav.settings import EnvSettings, make_env
from sb3_dcqn.replay import DCQNHerReplayBuffer, RevisionHerReplayBuffer

GOAL_ENV = "CampusNavGoal-v0"
FAST = ("--encoder", "pixels", "--render-size", "64", "48")
# The shipped entry's buffer and relabelling, with short episodes, a small buffer and small networks; three goals held
# out of training
TINY_GOAL_CONF = """\
CampusNavGoal-v0:
  n_timesteps: 300
  policy: 'MultiInputPolicy'
  env_kwargs:
    view_dim: 16
    max_steps: 30
    held_out_goals: [3, 5, 17]
  replay_buffer_class: HerReplayBuffer
  replay_buffer_kwargs: "dict(n_sampled_goal=4, goal_selection_strategy='future')"
  buffer_size: 2000
  learning_starts: 100
  batch_size: 32
  train_freq: 4
  target_update_interval: 100
  policy_kwargs: "dict(features_extractor_class=EmbeddingFusionExtractor, features_extractor_kwargs=dict(embed_dim=16, \
features_dim=16), share_features_extractor=True, net_arch=[16], heading_key='heading')"
"""
ROAD = ("14", "15")  # a road of the built-in campus with a way around it
BRIDGE = ("0", "11")  # node 0's only road: closing it cuts an intersection (a goal of the goal env) off


# The session's feature cache: the views are rendered and encoded once, not once per test or module (conftest.py)
pytestmark = pytest.mark.usefixtures("shared_feature_cache")


@pytest.fixture
def tiny_conf(tmp_path: Path) -> Path:
    path = tmp_path / "tiny_goal.yml"
    path.write_text(TINY_GOAL_CONF)
    return path


def cli(*argv: str) -> dict:
    return run(build_parser().parse_args(list(argv)))


def tensorboard_tags(folder: Path) -> dict[str, set[str]]:
    events = EventAccumulator(str(folder))
    events.Reload()
    tags = events.Tags()
    return {"scalars": set(tags["scalars"]), "images": set(tags["images"])}


def test_the_shipped_entry_trains_with_hindsight_relabelling_and_scores_routes_to_every_goal(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "goal"
    summary = cli(
        "train", "--env", GOAL_ENV, *FAST, "--no-replay-buffer", "--no-progress",
        *("--timesteps", "1100", "--eval-freq", "1100", "--out", str(out)),
    )  # fmt: skip
    printed = capsys.readouterr()
    assert "| trained |" in printed.out and "note:" not in printed.err  # train has no default levers to leave out
    # Every intersection is a goal: 101 goals, every (start, heading) that can reach each
    assert summary["trained"]["n_routes"] == 101 * 100 * 4 and summary["num_timesteps"] >= 1100
    assert summary["levers"] == [] and summary["settings"]["env"] == GOAL_ENV
    saved = json.loads((out / "dcqn_campusnav.env.json").read_text())["settings"]
    assert saved["env"] == GOAL_ENV and saved["env_kwargs"] == {"view_dim": 64}
    for name in ("routes.png", "curves.png", "dcqn_campusnav.zip", "summary.json"):
        assert (out / name).is_file(), name
    # routes.png: the four landmark goals' routes in a 2 x 2 grid (each map is wider than tall), not a tall column
    height, width = cv2.imread(str(out / "routes.png")).shape[:2]
    assert 0.6 < height / width < 1.2
    tags = tensorboard_tags(out / "tb" / "DCQN-memory_1")  # the shipped goal entry wears the route memory
    assert {"eval/success_rate", "train/critic_1_loss", "train/q_mean"} <= tags["scalars"]
    assert {"figures/routes", "figures/curves"} <= tags["images"]
    model = DCQN.load(out / "dcqn_campusnav.zip", env=make_env(EnvSettings.from_json(saved)))
    assert isinstance(model.replay_buffer, DCQNHerReplayBuffer)  # the YAML's HerReplayBuffer, served by DCQN's


def test_a_goal_env_model_recovers_from_a_closure_on_its_routes_readapts_and_is_evaluated_and_drawn(
    tmp_path: Path, tiny_conf: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "tiny"
    summary = cli(
        "train", "--env", GOAL_ENV, "--conf", str(tiny_conf), *FAST, "--close-on-route", "busiest", "--no-progress",
        *("--timesteps", "300", "--eval-freq", "300", "--recovery-budget", "100", "--out", str(out)),
    )  # fmt: skip
    printed = capsys.readouterr().out
    assert "| closure | roads |" in printed
    # Every intersection is protected: the busiest road that closes has a way around it
    (closure,) = summary["closures"]
    assert len(closure["closed"]) == 1 and closure["routes_affected"] > 0 and not closure["refused"]
    assert closure["last"]["n_routes"] == 101 * 100 * 4
    model = out / "dcqn_campusnav.zip"
    assert (out / "dcqn_campusnav_replay_buffer.pkl").is_file()
    assert (out / "routes.png").is_file()

    # readapt: the HER buffer loads with the env and training goes on
    readapted = cli("readapt", str(model), "--close", *ROAD, "--timesteps", "100", "--no-progress")
    printed = capsys.readouterr()
    assert "replay buffer:" in printed.err and "(400 transitions)" in printed.err
    assert readapted["closures"][0]["closed"] == [[int(ROAD[0]), int(ROAD[1])]]
    assert (out / "readapt" / "dcqn_campusnav_replay_buffer.pkl").is_file()

    # evaluate: a row per landmark goal pictured, not 101; the held-out goals have a row of their own; --goal takes
    # an intersection's id
    scores = cli("evaluate", str(model), "--close", *ROAD, "--goal", "17")
    printed = capsys.readouterr().out
    assert all(f"| {goal} |" in printed for goal in GOALS) and "| node 17 |" in printed and "| node 3 |" not in printed
    assert "| training goals (98) |" in printed and "| held-out goals (3) |" in printed
    assert "every one of the 101 goals" in printed and f"roads closed: {ROAD[0]}-{ROAD[1]}" in printed
    assert len(scores["goals"]) == 101 and scores["all"]["n_routes"] == 101 * 100 * 4  # every node still reachable
    assert scores["groups"]["held-out goals (3)"]["n_routes"] == 3 * 100 * 4

    drawn = cli("draw", "--model", str(model), "--goal", "Cinema", "--start", "3", "--picture", str(tmp_path / "r.png"))
    assert (tmp_path / "r.png").is_file() and drawn["route"]["start"] == 3


def test_a_closure_that_cuts_off_any_intersection_is_refused_on_the_goal_env(tmp_path: Path) -> None:
    # Every intersection can be the goal: a road without a way around it cannot close
    with pytest.raises(CommandError, match=r"--close: .*close 0-11: .*cut protected node 0 off"):
        cli("train", "--env", GOAL_ENV, *FAST, "--close", *BRIDGE, "--out", str(tmp_path / "out"))


@pytest.mark.parametrize("lever", ["prioritized"])
def test_levers_that_do_not_combine_with_hindsight_relabelling_are_refused_by_name(tmp_path: Path, lever: str) -> None:
    message = rf"--levers: lever '{lever}' .*HerReplayBuffer.*every goal it is relabelled with"
    with pytest.raises(CommandError, match=message):
        cli("train", "--env", GOAL_ENV, *FAST, "--levers", "blocked", lever, "--out", str(tmp_path / "out"))
    assert not (tmp_path / "out").exists()  # refused before anything is trained or written


def test_demo_on_the_goal_env_runs_the_default_levers_revision_included(
    tmp_path: Path, tiny_conf: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    summary = cli(
        "demo", "--env", GOAL_ENV, "--conf", str(tiny_conf), *FAST, "--n-closures", "0", "--no-progress",
        *("--timesteps", "150", "--eval-freq", "150", "--out", str(tmp_path / "demo")),
    )  # fmt: skip
    assert summary["levers"] == ["revision", "blocked"]  # as on CampusNav-v0: DCQN's HER buffer revises too
    assert "left out" not in capsys.readouterr().err
    model = DCQN.load(
        tmp_path / "demo" / "dcqn_campusnav.zip", env=make_env(EnvSettings.from_json(summary["settings"]))
    )
    assert model.blocked_action_target and model.replay_buffer_class is RevisionHerReplayBuffer
    assert isinstance(model.replay_buffer, RevisionHerReplayBuffer)


def test_pictures_show_the_papers_four_goals_of_a_goal_env() -> None:
    nav = make_env(EnvSettings(GOAL_ENV, {"view_dim": 16}, "pixels", render_size=(64, 48)))
    assert len(nav.goal_names) == 101
    assert picture_goals(nav) == list(GOALS)
    single = make_env(EnvSettings("CampusNav-v0", {"view_dim": 16}, "pixels", render_size=(64, 48)))
    assert picture_goals(single) == ["Dreese Lab"]
