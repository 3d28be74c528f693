"""The main job end to end on a small, fast configuration: train, close a road, re-train, write results."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sb3_dcqn.campusnav_job import build_parser, load_zoo_entry, run
from sb3_dcqn.fusion import EmbeddingFusionExtractor
from sb3_dcqn.zoo import default_hyperparams_path


def test_campusnav_entry_uses_the_fusion_extractor() -> None:
    n_timesteps, kwargs = load_zoo_entry(default_hyperparams_path(), "CampusNav-v0")
    assert n_timesteps > 0 and kwargs["policy"] == "MultiInputPolicy"
    assert kwargs["policy_kwargs"]["features_extractor_class"] is EmbeddingFusionExtractor


def test_job_trains_closes_a_road_and_writes_logs_pictures_and_model(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("CAMPUSNAV_CACHE", str(tmp_path / "cache"))
    args = build_parser().parse_args(
        [
            *("--encoder", "pixels", "--render-size", "64", "48"),
            *("--timesteps", "1200", "--retrain-timesteps", "200", "--report-every", "600"),
            *("--out", str(tmp_path / "run")),
        ]
    )
    summary = run(args)
    printed = capsys.readouterr().out
    assert "[train] 1200 steps" in printed and "| re-trained |" in printed
    out = tmp_path / "run"
    for name in ("routes.png", "summary.json", "summary.md", "dcqn_campusnav.zip"):
        assert (out / name).is_file(), name
    assert json.loads((out / "summary.json").read_text())["closed_road"] == summary["closed_road"]
    u, v = summary["closed_road"]
    assert summary["trained"]["n_routes"] > 0
    events = EventAccumulator(str(out / "tb" / "DCQN_1"))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    assert {"routes/trained_success_rate", "routes/readapted_spl", "train/critic_2_loss"} <= tags
    assert u != v


def test_job_reports_bad_hyperparameter_files_clearly(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"nope\.yml"):
        load_zoo_entry(tmp_path / "nope.yml", "CampusNav-v0")
    conf = tmp_path / "conf.yml"
    conf.write_text("CartPole-v1:\n  policy: MlpPolicy\n")
    with pytest.raises(KeyError, match="CampusNav-v0"):
        load_zoo_entry(conf, "CampusNav-v0")
    with pytest.raises(KeyError, match="n_timesteps"):
        load_zoo_entry(conf, "CartPole-v1")
    conf.write_text("CartPole-v1:\n  n_timesteps: 10\n  policy_kwargs: 'dict(net_arch=[64'\n")
    with pytest.raises(ValueError, match="policy_kwargs"):
        load_zoo_entry(conf, "CartPole-v1")
