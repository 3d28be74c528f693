"""What ``dcqn-campusnav`` keeps of a run: no subcommand replaces an earlier run's results (a folder or picture that
holds them is kept, and the next numbered one written, as the RL Zoo numbers its runs; ``--force`` writes over them),
readapt and evaluate go on from the model as it was saved (its closures, levers and callbacks), and Ctrl-C saves the
run's work.

Each test trains the built-in campus for a few hundred steps with the cheap ``pixels`` encoder on 64 x 48 views (read
from the session's feature cache).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from cli_runs_support import FAST, ROAD, CtrlC, cli
from stable_baselines3.common.callbacks import BaseCallback
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from campusnav_env.callbacks import StartCurriculumCallback
from sb3_dcqn import DCQN
from sb3_dcqn.adaptation_boost import AdaptationBoost
from sb3_dcqn.campusnav import experiments
from sb3_dcqn.campusnav.cli import CommandError, main

# The session's feature cache: the views are rendered and encoded once, not once per test or module (conftest.py)
pytestmark = pytest.mark.usefixtures("shared_feature_cache")


def files_under(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def scalar_tags(folder: Path) -> set[str]:
    events = EventAccumulator(str(folder))
    events.Reload()
    return set(events.Tags()["scalars"])


class _Spy:
    """Wraps ``train_with_closures``: records the callbacks each run gets, optionally adds one of its own."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, extra: BaseCallback | None = None) -> None:
        self.callbacks: list[list[BaseCallback]] = []
        self.extra = extra
        self._original = experiments.train_with_closures
        monkeypatch.setattr(experiments, "train_with_closures", self)

    def __call__(self, *args: Any, callbacks: list[BaseCallback], **kwargs: Any) -> Any:
        self.callbacks.append(list(callbacks))
        extra = [self.extra] if self.extra is not None else []
        return self._original(*args, callbacks=[*callbacks, *extra], **kwargs)


# ------------------------------------------------------------------------------------------------ output folders
def test_demo_and_train_default_to_folders_of_their_own(
    tmp_path: Path, conf: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    cli("train", *FAST, "--conf", str(conf), "--timesteps", "100", "--eval-freq", "100")
    train = files_under(tmp_path / "runs" / "campusnav-train")
    cli("demo", *FAST, "--conf", str(conf), "--timesteps", "100", "--eval-freq", "100", "--n-closures", "0")
    demo = tmp_path / "runs" / "campusnav-demo"
    assert json.loads((demo / "summary.json").read_text())["command"] == "demo"
    assert files_under(tmp_path / "runs" / "campusnav-train") == train  # the demo replaced none of train's files
    assert json.loads(train["summary.json"])["command"] == "train" and "dcqn_campusnav_replay_buffer.pkl" in train


@pytest.mark.parametrize("command", ["train", "demo", "bare"])
def test_a_second_run_into_a_folder_with_results_writes_the_next_numbered_folder(
    tmp_path: Path, conf: Path, command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "runs" / "fixed"
    argv = {
        "train": ["train", "--timesteps", "100"],
        "demo": ["demo", "--timesteps", "100", "--n-closures", "0"],
        "bare": ["--timesteps", "100", "--n-closures", "0"],  # the main job: demo without a subcommand
    }[command]
    argv += [*FAST, "--conf", str(conf), "--eval-freq", "100", "--out", str(out)]
    main(argv)
    first = files_under(out)
    main(argv)
    second = tmp_path / "runs" / "fixed_2"
    error = capsys.readouterr().err
    assert f"--out {out} holds an earlier run's results (kept): writing to {second}" in error
    assert files_under(out) == first  # not a byte of the first run changed
    assert (second / "dcqn_campusnav.zip").is_file() and [p.name for p in (second / "tb").iterdir()] == ["DCQN_1"]
    main(argv)  # and the third
    assert (tmp_path / "runs" / "fixed_3" / "summary.json").is_file() and files_under(out) == first
    # --force: into the folder asked for, all the same
    main([*argv, "--force"])
    assert sorted(p.name for p in (out / "tb").iterdir()) == ["DCQN_1", "DCQN_2"]
    assert not (tmp_path / "runs" / "fixed_4").exists()


def test_readapt_twice_keeps_the_first_readapted_run(tmp_path: Path, conf: Path) -> None:
    out = tmp_path / "train"
    cli("train", *FAST, "--conf", str(conf), "--timesteps", "100", "--eval-freq", "100", "--out", str(out))
    model = out / "dcqn_campusnav.zip"
    trained = model.read_bytes()
    for _ in range(2):
        cli("readapt", str(model), *FAST[-1:], "--close", *map(str, ROAD), "--timesteps", "50", "--open-map")
    first = out / "readapt"
    assert (first / "summary.json").is_file() and (out / "readapt_2" / "summary.json").is_file()
    assert model.read_bytes() == trained  # the input model is never replaced without --in-place
    assert json.loads((first / "summary.json").read_text())["files"]["model"] == str(first / "dcqn_campusnav.zip")


@pytest.mark.parametrize("command", ["evaluate", "draw"])
def test_a_picture_that_exists_is_kept_and_the_next_numbered_name_written(
    tmp_path: Path, conf: Path, command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "train"
    cli("train", *FAST, "--conf", str(conf), "--timesteps", "100", "--eval-freq", "100", "--out", str(out))
    picture = tmp_path / "routes.png"
    model = str(out / "dcqn_campusnav.zip")
    argv = ["evaluate", model] if command == "evaluate" else ["draw", "--model", model]
    argv += ["--start", "3", "--picture", str(picture)]
    cli(*argv)
    kept = files_under(tmp_path)
    summary = cli(*argv)
    assert summary["picture"] == str(tmp_path / "routes_2.png") and (tmp_path / "routes_2.txt").is_file()
    assert f"{picture} exists, kept; --force writes over it" in capsys.readouterr().out
    assert {name: data for name, data in files_under(tmp_path).items() if name in kept} == kept
    assert cli(*argv, "--force")["picture"] == str(picture)


def test_roads_writes_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    before = files_under(tmp_path)
    cli("roads", "14")
    assert files_under(tmp_path) == before


# ------------------------------------------------------------------------------------------------ readapt, evaluate
def test_readapt_goes_on_with_the_saved_closures_levers_and_entry_callbacks(
    tmp_path: Path, conf: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "train"
    cli(
        "train", *FAST, "--conf", str(conf), "--levers", "boost", "--close", *map(str, ROAD), "--close-at", "100",
        *("--timesteps", "200", "--eval-freq", "100", "--keep-training", "--out", str(out)),
    )  # fmt: skip
    model = out / "dcqn_campusnav.zip"
    saved = json.loads((out / "dcqn_campusnav.env.json").read_text())
    assert saved["closed_roads_at_save"] == [list(ROAD)] and saved["levers"] == ["boost"]
    assert saved["callbacks"] == [["campusnav_env.callbacks.StartCurriculumCallback", {"initial": 2, "window": 5}]]

    spy = _Spy(monkeypatch)
    summary = cli("readapt", str(model), *FAST[-1:], "--close-random", "1", "--timesteps", "150", "--eval-freq", "100")
    (callbacks,) = spy.callbacks
    assert sorted(type(c).__name__ for c in callbacks) == ["AdaptationBoost", "StartCurriculumCallback"]
    assert summary["levers"] == ["boost"]
    assert "curriculum/start_distance_limit" in scalar_tags(out / "readapt" / "tb" / "DCQN_1")
    # The saved closure was in force from the start: the new one comes on top of it
    assert "closed again: 14-15" in capsys.readouterr().err
    again = json.loads((out / "readapt" / "dcqn_campusnav.env.json").read_text())["closed_roads_at_save"]
    (new_road,) = summary["closures"][0]["closed"]
    assert sorted(again) == sorted([list(ROAD), new_road])

    with pytest.raises(CommandError, match=r"road \(14, 15\) is already closed.*closed when the model was saved"):
        cli("readapt", str(model), "--close", *map(str, ROAD), "--out", str(tmp_path / "x"))

    # --open-map: only the new closure; --levers adds a callback lever, not one a model is built with
    summary = cli(
        "readapt", str(model), *FAST[-1:], "--open-map", "--close-random", "1", "--timesteps", "100",
        *("--levers", "boost", "--out", str(tmp_path / "open")),
    )  # fmt: skip
    assert [type(c) for c in spy.callbacks[-1]] == [AdaptationBoost, StartCurriculumCallback]
    assert len(json.loads((tmp_path / "open" / "dcqn_campusnav.env.json").read_text())["closed_roads_at_save"]) == 1
    with pytest.raises(CommandError, match=r"--levers revision: experience revision is set when a model is built.*"
                       r"its levers: boost"):  # fmt: skip
        cli("readapt", str(model), "--close-random", "1", "--levers", "revision", "--out", str(tmp_path / "x"))
    # The revision-triggered boost counts revisions of a replay buffer with revision, which this model does not have
    with pytest.raises(CommandError, match=r"--levers boost_on_revision: .* set when a model is built.*levers: boost"):
        cli("readapt", str(model), "--close-random", "1", "--levers", "boost_on_revision", "--out", str(tmp_path / "x"))
    assert not (tmp_path / "x").exists()


def test_evaluate_scores_the_model_on_the_map_it_was_saved_with(
    tmp_path: Path, conf: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "train"
    cli(
        "train", *FAST, "--conf", str(conf), "--close", *map(str, ROAD), "--close-at", "100",
        *("--timesteps", "200", "--eval-freq", "100", "--keep-training", "--out", str(out)),
    )  # fmt: skip
    model = str(out / "dcqn_campusnav.zip")
    restored = cli("evaluate", model)
    assert restored["closed_roads"] == [list(ROAD)] and "roads closed: 14-15" in capsys.readouterr().out
    open_map = cli("evaluate", model, "--open-map")
    assert open_map["closed_roads"] == [] and "saved with roads 14-15 closed" in capsys.readouterr().err
    drawn = cli("draw", "--model", model, "--picture", str(tmp_path / "route.png"))
    assert drawn["picture"] and "closed again: 14-15" in capsys.readouterr().err


def test_the_summary_is_of_the_model_saved_beside_it_also_after_readapt_in_place(
    tmp_path: Path, conf: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "fixed"
    summary = cli(
        "train", *FAST, "--conf", str(conf), "--close", *map(str, ROAD), "--close-at", "100",
        *("--timesteps", "300", "--eval-freq", "100", "--out", str(out)),
    )  # fmt: skip
    model = out / "dcqn_campusnav.zip"
    for step in range(2):
        beside = json.loads((out / "summary.json").read_text())
        assert beside["final"]["step"] == DCQN.load(model).num_timesteps  # the last evaluation is of the saved model
        scores = cli("evaluate", str(model))["all"]  # on the roads closed when it was saved
        assert beside["final"]["success_rate"] == pytest.approx(scores["success_rate"], abs=1e-9)
        assert beside["final"]["spl"] == pytest.approx(scores["spl"], abs=1e-9)
        if step == 0:
            assert beside["num_timesteps"] == summary["num_timesteps"]
            # The model replaced in place: so are the summary and pictures beside it
            cli("readapt", str(model), *FAST[-1:], "--in-place", "--close-random", "1", "--timesteps", "100")
            assert "--in-place: replacing" in capsys.readouterr().err
            assert json.loads((out / "summary.json").read_text())["command"] == "readapt"
    with pytest.raises(CommandError, match=r"--in-place writes the re-adapted model and its results beside"):
        cli("readapt", str(model), "--in-place", "--close-random", "1", "--out", str(tmp_path / "elsewhere"))


# ------------------------------------------------------------------------------------------------ Ctrl-C
def test_ctrl_c_saves_the_model_replay_buffer_and_closures_and_says_how_to_go_on(
    tmp_path: Path, conf: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    spy = _Spy(monkeypatch, extra=CtrlC(at=150))
    with pytest.raises(SystemExit) as exit_info:
        main(["train", *FAST, "--conf", str(conf), "--close", *map(str, ROAD), "--close-at", "100", "--out", str(out)])
    assert exit_info.value.code == 130
    error = capsys.readouterr().err
    model_path = out / "dcqn_campusnav.zip"
    (line,) = [text for text in error.splitlines() if "interrupted" in text]
    assert line.startswith(f"dcqn-campusnav train: interrupted at step 150: saved {model_path} with its replay buffer")
    assert f"dcqn-campusnav readapt {model_path} --in-place" in line and "Traceback" not in error

    model = DCQN.load(model_path)
    assert model.num_timesteps == 150
    model.load_replay_buffer(out / "dcqn_campusnav_replay_buffer.pkl")
    # SB3 calls the callbacks before it stores a step's transition: the interrupted step's is not in the buffer
    assert model.replay_buffer is not None and model.replay_buffer.size() == 149
    saved = json.loads((out / "dcqn_campusnav.env.json").read_text())
    assert saved["closed_roads_at_save"] == [list(ROAD)] and saved["num_timesteps"] == 150
    summary = json.loads((out / "summary.json").read_text())
    assert summary["command"] == "train" and summary["interrupted"] is True
    assert "Interrupted at step 150" in (out / "summary.md").read_text()  # no summary.md of another model
    assert not list(out.glob("*.tmp*"))  # every file written whole

    # The way on that the line names: readapt goes on from step 150 with the saved closure in force
    spy.extra = None
    readapted = cli("readapt", str(model_path), *FAST[-1:], "--in-place", "--close-random", "1", "--timesteps", "50")
    assert readapted["num_timesteps"] > 150
    assert len(json.loads((out / "dcqn_campusnav.env.json").read_text())["closed_roads_at_save"]) == 2
