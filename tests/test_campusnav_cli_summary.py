"""Every number a ``dcqn-campusnav`` run reports at its end is of the model file saved beside it.

``summary.json``'s ``final`` equals what ``dcqn-campusnav evaluate`` says of the saved zip (within 1e-9), and so do the
last row of ``summary.md``'s route table, TensorBoard's last point and the progress bar's last words, in every path: a
closure not recovered from by the end (issue 35's run: SB3 trains after the callbacks' last step, so an evaluation
made during that step is of another model), training without closures, a recovery (the route memory's), ``readapt``,
``train -i`` and Ctrl-C.

The runs use the cheap ``pixels`` encoder; the views are rendered once for the module.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from cli_runs_support import CtrlC, cli
from stable_baselines3.common.callbacks import BaseCallback
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sb3_dcqn.campusnav import experiments
from sb3_dcqn.campusnav.cli import main

# Issue 35's run: a closure at step 3000 that the agent has not recovered from when the budget ends at 6000
ISSUE_RUN = ("train", "--close", "69", "81", "--close-at", "3000", "--timesteps", "6000", "--encoder", "pixels")


@pytest.fixture(scope="module")
def views_cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """One feature cache for the module (the module-scoped runs need it before any per-test fixture)."""
    folder = tmp_path_factory.mktemp("cache")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("CAMPUSNAV_CACHE", str(folder))
        yield folder


@pytest.fixture(autouse=True)
def _module_views(views_cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CAMPUSNAV_CACHE", str(views_cache))


@pytest.fixture(scope="module")
def issue_run(views_cache: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """Issue 35's run, its folder and what it wrote to stderr (the progress bar on)."""
    import contextlib
    import io

    out = tmp_path_factory.mktemp("issue") / "fixed"
    error = io.StringIO()
    with contextlib.redirect_stderr(error):
        cli(*ISSUE_RUN, "--out", str(out))
    return out, error.getvalue()


def last_point(tb_folder: Path, tag: str) -> float:
    events = EventAccumulator(str(tb_folder))
    events.Reload()
    return events.Scalars(tag)[-1].value


def last_route_row(summary_md: str) -> list[str]:
    """The cells of the last row of the route table (``| phase | env step | episode | success rate | SPL | ...``)."""
    table = summary_md.split("| phase |", 1)[1].split("\n\n", 1)[0]
    return [cell.strip() for cell in table.strip().splitlines()[-1].strip("|").split("|")]


def assert_of_the_saved_model(out: Path) -> dict[str, Any]:
    """``out``'s summaries, TensorBoard's last point and env.json agree with ``evaluate`` of the model saved there."""
    summary = json.loads((out / "summary.json").read_text())
    final = summary["final"]
    saved = json.loads((out / "dcqn_campusnav.env.json").read_text())
    assert final["step"] == saved["num_timesteps"] == summary["num_timesteps"]
    scores = cli("evaluate", str(out / "dcqn_campusnav.zip"))["all"]  # with the roads closed when it was saved
    assert final["success_rate"] == pytest.approx(scores["success_rate"], abs=1e-9)
    assert final["spl"] == pytest.approx(scores["spl"], abs=1e-9)
    (tb_folder,) = (out / "tb").iterdir()
    assert last_point(tb_folder, "eval/success_rate") == pytest.approx(final["success_rate"], abs=1e-6)
    assert last_point(tb_folder, "eval/spl") == pytest.approx(final["spl"], abs=1e-6)
    if not summary.get("interrupted"):
        row = last_route_row((out / "summary.md").read_text())
        assert row[1:2] + row[3:5] == [str(final["step"]), f"{final['success_rate']:.3f}", f"{final['spl']:.3f}"]
    return summary


# ------------------------------------------------------------------------------------------------ train
def test_a_closure_not_recovered_from_by_the_end_reports_the_saved_model(issue_run: tuple[Path, str]) -> None:
    out, error = issue_run
    summary = assert_of_the_saved_model(out)
    assert summary["closures"][0]["closed"] == [[69, 81]] and not summary["closures"][0]["recovered"]
    assert summary["closures"][0]["last"]["success_rate"] == summary["final"]["success_rate"]
    # The bar's last words: what happened, with the saved model's scores (not those of the last step's evaluation)
    final = summary["final"]
    ending = f"not recovered from 69-81; at 6,000 steps: success {final['success_rate']:.3f}, SPL {final['spl']:.3f}"
    assert ending in error.replace("\r", "\n").strip().splitlines()[-1]


@pytest.mark.parametrize("n_envs", [1, 2])
def test_training_without_closures_reports_the_saved_model(tmp_path: Path, n_envs: int) -> None:
    out = tmp_path / "plain"
    summary = cli(
        "train", "--encoder", "pixels", "--timesteps", "1600", "--n-envs", str(n_envs), "--no-progress",
        "--out", str(out),
    )  # fmt: skip
    assert summary["closures"] == [] and summary["num_timesteps"] == 1600
    assert_of_the_saved_model(out)


@pytest.mark.parametrize("keep_training", [False, True])
def test_a_recovery_reports_the_saved_model_also_when_training_goes_on_after_it(
    tmp_path: Path, keep_training: bool, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "recovered"
    # The route memory solves the campus in about a thousand steps and recovers in a few episodes
    summary = cli(
        "train", "--encoder", "pixels", "-params", "route_memory:True", "--close-on-route", "busiest",
        "--timesteps", "1500", "--recovery-budget", "600", "--out", str(out),
        *(["--keep-training"] if keep_training else []),
    )  # fmt: skip
    (closure,) = summary["closures"]
    assert closure["recovered"]
    assert_of_the_saved_model(out)
    final, solved = summary["final"], summary["solved_at"]
    road = "-".join(map(str, closure["closed"][0]))
    lines = capsys.readouterr().err.replace("\r", "\n").splitlines()
    bars = [line for line in lines if "100%|" in line and "step/s" in line]  # the training bars, not the views
    if keep_training:  # trained past the recovery: the model saved is the one at the end, and the table says so
        assert final["step"] > closure["recovered_at"]["step"]
        assert last_route_row((out / "summary.md").read_text())[0] == "at the end (the model saved)"
        return
    # Each phase's bar ends full on what happened, its budget named: not at "30%" as if it had crashed
    assert bars[0].endswith(
        f"solved at {solved['step']:,} steps: success {solved['success_rate']:.3f}, SPL {solved['spl']:.3f} "
        "(budget 1,500 steps)]"
    )
    assert bars[-1].startswith(f"closed {road}: 100%|") and bars[-1].endswith(
        f"recovered from {road} after {closure['recovery_episodes']:,.0f} episodes ({closure['recovery_steps']:,.0f} "
        f"steps): success {final['success_rate']:.3f}, SPL {final['spl']:.3f} (budget 600 steps)]"
    )


# ------------------------------------------------------------------------------------------------ a saved run
def test_readapt_reports_the_readapted_model(issue_run: tuple[Path, str], tmp_path: Path) -> None:
    out = tmp_path / "readapted"
    model = issue_run[0] / "dcqn_campusnav.zip"
    summary = cli(
        "readapt", str(model), "--close-random", "1", "--timesteps", "1000", "--no-progress", "--out", str(out)
    )
    assert summary["num_timesteps"] > 6000
    assert_of_the_saved_model(out)


def test_train_i_reports_the_resumed_model(issue_run: tuple[Path, str], tmp_path: Path) -> None:
    out = tmp_path / "resumed"
    model = issue_run[0] / "dcqn_campusnav.zip"
    summary = cli("train", "-i", str(model), "--timesteps", "1000", "--no-progress", "--out", str(out))
    assert summary["num_timesteps"] == 7000
    assert_of_the_saved_model(out)


def test_ctrl_c_reports_the_model_it_saved(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    original = experiments.train_with_closures

    def interrupted(*args: Any, callbacks: list[BaseCallback], **kwargs: Any) -> Any:
        return original(*args, callbacks=[*callbacks, CtrlC(at=1500)], **kwargs)

    monkeypatch.setattr(experiments, "train_with_closures", interrupted)
    out = tmp_path / "interrupted"
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--encoder", "pixels", "--timesteps", "6000", "--no-progress", "--out", str(out)])
    assert exit_info.value.code == 130
    monkeypatch.setattr(experiments, "train_with_closures", original)
    summary = assert_of_the_saved_model(out)
    assert summary["interrupted"] is True and summary["final"]["step"] == 1500
    final = summary["final"]
    text = (out / "summary.md").read_text()
    assert "Interrupted at step 1500" in text
    assert f"success {final['success_rate']:.3f}, SPL {final['spl']:.3f}" in text
