"""What a newcomer met on a fresh clone (issue 47), as the command line must answer it.

- ``readapt`` of the demo's own model (which keeps no replay buffer) with a closure that needs no training ends like
  any run: a summary, the model and its settings file naming the closures it was trained under (it ended in a
  traceback from the empty buffer's file, leaving a model without them).
- A save that fails writes no model file: a run folder that failed never looks finished.
- ``evaluate`` of a model without its settings file says that the closures it was trained under are not known
  (it scored it on the open map without a word).
- ``--device cuda`` on a machine without CUDA is refused in one line, exit status 2 (it trained on the CPU, exit 0).
- ``--save-freq`` on a run that stops (solved) before its first checkpoint says why none was written.

Each run trains the built-in campus for a few hundred steps with the cheap ``pixels`` encoder on 64 x 48 views.
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import pytest
import torch
from cli_runs_support import FAST, ROAD, cli

from sb3_dcqn.campusnav import experiments, model_files, solved
from sb3_dcqn.campusnav.cli import main

pytestmark = pytest.mark.usefixtures("shared_feature_cache")


@pytest.fixture
def demo_model(tmp_path: Path, conf: Path) -> Path:
    """A demo run's model: the demo saves no replay buffer."""
    out = tmp_path / "demo"
    cli(
        "demo",
        *FAST,
        "--conf",
        str(conf),
        "--timesteps",
        "100",
        "--eval-freq",
        "100",
        "--n-closures",
        "0",
        "--out",
        str(out),
    )
    assert not (out / "dcqn_campusnav_replay_buffer.pkl").exists()
    return out / "dcqn_campusnav.zip"


@pytest.fixture
def recovered_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every route evaluation at the recovery bar: a closure is recovered from before a step is trained."""
    monkeypatch.setattr(experiments, "DEFAULT_SUCCESS_THRESHOLD", 0.0)
    monkeypatch.setattr(experiments, "DEFAULT_SPL_THRESHOLD", 0.0)


def fails(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run the command line, expect exit status 2 and one line on stderr, no traceback; return the line."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "Traceback" not in error, error
    return error


@pytest.mark.usefixtures("recovered_at_once")
def test_readapt_of_the_demo_model_with_a_closure_that_needs_no_training_finishes(demo_model: Path) -> None:
    summary = cli("readapt", str(demo_model), "--no-progress", "--close", *map(str, ROAD))
    out = demo_model.parent / "readapt"
    assert summary["num_timesteps"] <= 101  # recovered at once: one env step, stopped before it is stored
    assert (out / "summary.json").is_file() and (out / "summary.md").is_file()
    saved = json.loads((out / "dcqn_campusnav.env.json").read_text())
    assert saved["closed_roads_at_save"] == [list(ROAD)]  # the model says which closures it was trained under
    with (out / "dcqn_campusnav_replay_buffer.pkl").open("rb") as file:
        assert pickle.load(file).size() == 0  # its buffer, empty, saved and readable


@pytest.mark.usefixtures("recovered_at_once")
def test_a_run_whose_save_fails_leaves_no_model_file(demo_model: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(buffer: object, file: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(model_files, "dump_compact_buffer", broken)
    with pytest.raises(OSError, match="disk full"):
        cli("readapt", str(demo_model), "--no-progress", "--close", *map(str, ROAD))
    out = demo_model.parent / "readapt"
    left = {p.name for p in out.iterdir()}
    assert left <= {"tb"}, left  # its TensorBoard log only: no model, no pictures, no summary


def test_evaluate_says_when_a_model_does_not_say_which_closures_it_was_trained_under(
    demo_model: Path, conf: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    demo_model.with_suffix(".env.json").unlink()  # as DCQN.save writes a model: no settings file beside it
    capsys.readouterr()
    cli("evaluate", str(demo_model), *FAST[:-1], "--conf", str(conf))
    error = capsys.readouterr().err
    assert "dcqn_campusnav.env.json beside it, so the closures it was trained under are not known" in error
    assert "starting from the open map" in error


@pytest.mark.parametrize("device", ["cuda", "cuda:0"])
def test_device_cuda_without_cuda_is_refused_in_one_line(
    device: str, tmp_path: Path, conf: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)  # whatever this machine has
    out = tmp_path / "run"
    error = fails(["train", *FAST, "--conf", str(conf), "--device", device, "--out", str(out)], capsys)
    assert f"--device {device}: CUDA is not available on this machine" in error and "--device cpu" in error
    assert not out.exists()


def test_device_cuda_past_the_last_gpu_is_refused(
    tmp_path: Path, conf: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    error = fails(["train", *FAST, "--conf", str(conf), "--device", "cuda:3", "--out", str(tmp_path / "r")], capsys)
    assert "--device cuda:3: this machine has 1 CUDA device(s), cuda:0..cuda:0" in error


def test_save_freq_on_a_run_that_stops_before_its_first_checkpoint_says_why(
    tmp_path: Path, conf: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(solved, "SOLVED_SUCCESS", 0.0)  # solved at the first route evaluation
    monkeypatch.setattr(solved, "SOLVED_SPL", 0.0)
    out = tmp_path / "run"
    budget = ("--timesteps", "300", "--eval-freq", "100", "--save-freq", "200")
    cli("train", *FAST, "--conf", str(conf), *budget, "--out", str(out))
    assert not (out / "checkpoints").exists()
    error = capsys.readouterr().err
    assert "no checkpoint written: training ended after 100 steps, before --save-freq 200" in error
    assert "add --keep-training" in error
    cli("train", *FAST, "--conf", str(conf), *budget, "--keep-training", "--out", str(tmp_path / "kept"))
    assert (tmp_path / "kept" / "checkpoints" / "dcqn_campusnav_200_steps.zip").is_file()
    assert "no checkpoint written" not in capsys.readouterr().err
