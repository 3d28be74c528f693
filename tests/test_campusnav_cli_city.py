"""The command line on CampusNavCity-v0: an entry's curriculum callback, n-step returns, lean replay and the route
memory run through ``dcqn-campusnav train`` as they are, and the saved model evaluates with its memory."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from campusnav_env import figures
from campusnav_env.figures import CURRICULUM_NOTE, training_curves
from sb3_dcqn import DCQN
from sb3_dcqn.campusnav.cli import build_parser, run
from sb3_dcqn.replay import LeanNStepDictReplayBuffer
from sb3_dcqn.route_memory import RouteMemoryDCQN
from sb3_dcqn.route_memory.layer import saved_algorithm_class

CITY = "CampusNavCity-v0"
FAST = ("--encoder", "pixels", "--render-size", "64", "48")
# The shipped city entry's levers on a small city, with small networks and a short run
TINY_CITY_CONF = """\
CampusNavCity-v0:
  n_timesteps: 600
  policy: 'MultiInputPolicy'
  env_kwargs:
    n_intersections: 60
    view_dim: 16
  gamma: 0.98
  n_steps: 4
  replay_buffer_class: LeanDictReplayBuffer
  route_memory: True
  buffer_size: 2000
  learning_starts: 100
  batch_size: 32
  target_update_interval: 100
  callback:
    - campusnav_env.callbacks.StartCurriculumCallback:
        initial: 2
        window: 5
  policy_kwargs: "dict(features_extractor_class=EmbeddingFusionExtractor, features_extractor_kwargs=dict(embed_dim=16, \
features_dim=16), share_features_extractor=True, net_arch=[16], heading_key='heading')"
"""


@pytest.fixture(autouse=True)
def _own_feature_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setenv("CAMPUSNAV_CACHE", str(tmp_path / "cache"))
    yield


def cli(*argv: str) -> dict:
    return run(build_parser().parse_args(list(argv)))


def test_the_city_entry_trains_with_its_curriculum_and_lean_n_step_replay_and_evaluates_with_its_route_memory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    notes = []

    def curves(*args: Any, **kwargs: Any) -> np.ndarray:
        notes.append(kwargs.get("note"))
        return training_curves(*args, **kwargs)

    monkeypatch.setattr(figures, "training_curves", curves)
    conf = tmp_path / "city.yml"
    conf.write_text(TINY_CITY_CONF)
    out = tmp_path / "city"
    summary = cli(
        "train", "--env", CITY, "--conf", str(conf), *FAST, "--no-progress",
        *("--timesteps", "600", "--eval-freq", "300", "--out", str(out)),
    )  # fmt: skip
    assert summary["settings"]["env"] == CITY and summary["num_timesteps"] >= 600
    assert summary["trained"]["n_routes"] > 0
    events = EventAccumulator(str(out / "tb" / "DCQN-memory_1"))  # the entry wears the route memory
    events.Reload()
    assert "curriculum/start_distance_limit" in events.Tags()["scalars"]  # the entry's callback ran
    # ... so the curves say why episode reward (curriculum starts, near the goal) runs ahead of route success
    assert notes == [CURRICULUM_NOTE]
    model = saved_algorithm_class(out / "dcqn_campusnav.zip", DCQN).load(out / "dcqn_campusnav.zip")
    assert (
        type(model) is RouteMemoryDCQN
        and model.route_memory
        and model.explores_untried
        and model.replay_buffer_class is LeanNStepDictReplayBuffer
        and model.n_steps == 4
    )
    model.load_replay_buffer(out / "dcqn_campusnav_replay_buffer.pkl")
    assert type(model.replay_buffer) is LeanNStepDictReplayBuffer and model.replay_buffer.n_steps == 4
    assert model.memory is not None and model.memory.n_states > 0  # the memory travels in the model's file
    scores = cli("evaluate", str(out / "dcqn_campusnav.zip"))
    assert scores["all"]["n_routes"] == summary["trained"]["n_routes"]
    assert scores["all"]["success_rate"] == pytest.approx(summary["trained"]["success_rate"])
