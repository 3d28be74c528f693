"""
Resuming an interrupted run from its last checkpoint, in a fresh process.

A run with a budget of ``TOTAL`` steps writes a checkpoint (model and replay buffer, SB3's ``CheckpointCallback``) every
``SAVE_FREQ`` steps and dies at step ``CRASH_AT``, without any clean-up. A second process loads the last checkpoint and
its replay buffer and learns the remaining steps with ``reset_num_timesteps=False``. Both runs are this file run as a
script (``python tests/test_resume.py interrupted|resumed FOLDER``); they write what they hold, and the tests compare.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.utils import LinearSchedule

from sb3_dcqn import DCQN

TOTAL, SAVE_FREQ, CRASH_AT = 200, 40, 110
LAST_SAVE = CRASH_AT // SAVE_FREQ * SAVE_FREQ  # 80: the checkpoint the user restarts from
CRASHED = 17  # exit status of the interrupted run
LEARNING_STARTS = 20
# Both schedules span the whole budget, so that every step has its own exploration rate and learning rate
LEARNING_RATE = LinearSchedule(1e-3, 1e-4, 1.0)
EXPLORATION = LinearSchedule(1.0, 0.05, 1.0)
KWARGS: dict[str, Any] = dict(
    learning_rate=LEARNING_RATE,
    exploration_initial_eps=EXPLORATION.start,
    exploration_final_eps=EXPLORATION.end,
    exploration_fraction=EXPLORATION.end_fraction,
    learning_starts=LEARNING_STARTS,
    train_freq=1,  # one step per rollout, one gradient step after each
    batch_size=16,
    buffer_size=1_000,
    target_update_interval=30,
    policy_kwargs=dict(net_arch=[16]),
    seed=0,
)
COUNTERS = ("num_timesteps", "_n_calls", "_n_updates", "_episode_num")
BUFFER_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


# --- the two runs (executed in subprocesses) -------------------------------------------------------------------------


def training_state(model: DCQN) -> dict[str, Any]:
    """Everything a resumed run has to take over, as numbers and tensors (loadable with ``weights_only=True``)."""
    buffer = model.replay_buffer
    assert buffer is not None
    return {
        "counters": {name: getattr(model, name) for name in COUNTERS},
        "exploration_rate": model.exploration_rate,
        "progress_remaining": model._current_progress_remaining,
        "policy": model.policy.state_dict(),  # online and target critics
        "optimizer": model.policy.optimizer.state_dict(),
        "replay_buffer": {
            "pos": buffer.pos,
            "full": buffer.full,
            **{name: th.from_numpy(getattr(buffer, name).copy()) for name in BUFFER_ARRAYS},
        },
    }


class SaveState(BaseCallback):
    """Writes the live training state at every checkpoint (placed after the ``CheckpointCallback``: same moment)."""

    def __init__(self, folder: Path) -> None:
        super().__init__()
        self.folder = folder

    def _on_step(self) -> bool:
        if self.n_calls % SAVE_FREQ == 0:
            th.save(training_state(self.model), self.folder / f"state_{self.num_timesteps}.pt")
        return True


class RecordSchedules(BaseCallback):
    """Appends ``step, progress remaining, exploration rate, learning rate`` before every rollout (survives a crash)."""

    def __init__(self, folder: Path) -> None:
        super().__init__()
        self.path = folder / "schedules.txt"

    def _on_rollout_start(self) -> None:
        model = self.model
        row = (model._current_progress_remaining, model.exploration_rate, model.policy.optimizer.param_groups[0]["lr"])
        with self.path.open("a") as file:
            # repr() writes floats so that they read back bit for bit
            file.write(" ".join([str(model.num_timesteps), *map(repr, row)]) + "\n")

    def _on_step(self) -> bool:
        return True


class Crash(BaseCallback):
    """Kills the process at a step, as a power cut would: no clean-up, no final save."""

    def __init__(self, at: int) -> None:
        super().__init__()
        self.at = at

    def _on_step(self) -> bool:
        if self.num_timesteps == self.at:
            os._exit(CRASHED)
        return True


def interrupted_run(folder: Path) -> None:
    probes = folder / "interrupted"
    probes.mkdir()
    model = DCQN("MlpPolicy", make_vec_env("CartPole-v1", seed=0), tensorboard_log=str(folder / "tb"), **KWARGS)
    checkpoints = CheckpointCallback(SAVE_FREQ, str(folder / "checkpoints"), "dcqn", save_replay_buffer=True)
    model.learn(
        TOTAL, callback=[checkpoints, SaveState(probes), RecordSchedules(probes), Crash(CRASH_AT)], log_interval=1
    )


def resumed_run(folder: Path) -> None:
    (folder / "resumed").mkdir()
    checkpoints = folder / "checkpoints"
    last = max(int(path.stem.split("_")[-2]) for path in checkpoints.glob("dcqn_*_steps.zip"))
    model = DCQN.load(checkpoints / f"dcqn_{last}_steps.zip", env=make_vec_env("CartPole-v1", seed=1))
    model.load_replay_buffer(checkpoints / f"dcqn_replay_buffer_{last}_steps.pkl")
    th.save(training_state(model), folder / "resumed" / "loaded.pt")
    model.learn(
        TOTAL - model.num_timesteps,
        callback=RecordSchedules(folder / "resumed"),
        log_interval=1,
        tb_log_name="DCQN",
        reset_num_timesteps=False,
    )
    th.save(training_state(model), folder / "resumed" / "final.pt")


# --- the tests -------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("resume")
    for phase, expected_status in (("interrupted", CRASHED), ("resumed", 0)):
        result = subprocess.run(
            [sys.executable, __file__, phase, str(folder)],
            cwd=folder,
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
        assert result.returncode == expected_status, result.stderr[-3000:]
    return folder


def load_state(path: Path) -> dict[str, Any]:
    return th.load(path, weights_only=True)


def assert_identical(actual: Any, expected: Any, where: str = "state") -> None:
    if isinstance(expected, dict):
        assert actual.keys() == expected.keys(), where
        for key in expected:
            assert_identical(actual[key], expected[key], f"{where}[{key!r}]")
    elif isinstance(expected, th.Tensor):
        assert th.equal(actual, expected), where
    else:
        assert actual == expected, where


def read_schedules(folder: Path) -> np.ndarray:
    """Rows of ``step, progress remaining, exploration rate, learning rate``, one per rollout."""
    return np.loadtxt(folder / "schedules.txt", ndmin=2)


def test_the_last_checkpoint_loads_in_a_fresh_process_with_the_state_of_the_run_at_the_save_point(runs: Path) -> None:
    live = load_state(runs / "interrupted" / f"state_{LAST_SAVE}.pt")
    loaded = load_state(runs / "resumed" / "loaded.pt")
    # A round trip of stored numbers: counters, exploration rate, progress, online and target critics, Adam's step
    # counts and moments, the replay buffer's position, fill flag and contents must all come back bit for bit
    assert_identical(loaded, live)
    assert loaded["counters"]["num_timesteps"] == LAST_SAVE
    # The checkpoint is written in the callback of step k, before step k's transition is stored
    assert loaded["replay_buffer"]["pos"] == LAST_SAVE - 1 and not loaded["replay_buffer"]["full"]
    adam_steps = {state["step"].item() for state in loaded["optimizer"]["state"].values()}
    assert adam_steps == {loaded["counters"]["_n_updates"]} and loaded["counters"]["_n_updates"] > 0


def test_schedules_continue_over_the_whole_budget_instead_of_restarting(runs: Path) -> None:
    interrupted = read_schedules(runs / "interrupted")
    resumed = read_schedules(runs / "resumed")
    # Rows after a gradient step (the learning rate is set by the update) and, for the resumed run, after its first
    # rollout (which starts from the checkpoint's own values, compared exactly above)
    interrupted = interrupted[interrupted[:, 0] > LEARNING_STARTS]
    resumed = resumed[resumed[:, 0] > LAST_SAVE]
    assert resumed[-1, 0] == TOTAL - 1 and interrupted[-1, 0] == CRASH_AT - 1
    for rows in (interrupted, resumed):
        progress = 1 - rows[:, 0] / TOTAL
        # The same double-precision formulas recomputed here: 1e-12 leaves room for rounding only. A restarted
        # schedule would be back at exploration_initial_eps = 1.0 and the initial learning rate after the checkpoint
        np.testing.assert_allclose(rows[:, 1], progress, rtol=1e-12)
        np.testing.assert_allclose(rows[:, 2], [EXPLORATION(p) for p in progress], rtol=1e-12)
        np.testing.assert_allclose(rows[:, 3], [LEARNING_RATE(p) for p in progress], rtol=1e-12)
    # Where both runs got to, the resumed run has what the interrupted run had
    both = np.intersect1d(interrupted[:, 0], resumed[:, 0])
    assert len(both) == CRASH_AT - LAST_SAVE - 1
    np.testing.assert_allclose(
        resumed[np.isin(resumed[:, 0], both), 1:], interrupted[np.isin(interrupted[:, 0], both), 1:], rtol=1e-12
    )


def test_resumed_run_goes_on_with_the_same_optimizer_target_cadence_and_replay_buffer(runs: Path) -> None:
    loaded = load_state(runs / "resumed" / "loaded.pt")
    final = load_state(runs / "resumed" / "final.pt")
    new_steps = TOTAL - LAST_SAVE
    assert final["counters"]["num_timesteps"] == TOTAL
    # One gradient step and one target-update tick per new step, counted on from the checkpoint's counters
    assert final["counters"]["_n_updates"] == loaded["counters"]["_n_updates"] + new_steps
    assert final["counters"]["_n_calls"] == loaded["counters"]["_n_calls"] + new_steps
    # Adam's step counts continue (a fresh optimizer would count the new updates only)
    for state in final["optimizer"]["state"].values():
        assert state["step"].item() == final["counters"]["_n_updates"]
    # The buffer is appended to, not replaced
    before, after = loaded["replay_buffer"], final["replay_buffer"]
    assert after["pos"] == before["pos"] + new_steps
    for name in BUFFER_ARRAYS:
        assert th.equal(after[name][: before["pos"]], before[name][: before["pos"]]), name


def test_tensorboard_run_continues_in_the_same_folder(runs: Path) -> None:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    tb = runs / "tb"
    assert [path.name for path in tb.iterdir()] == ["DCQN_1"]  # not DCQN_2
    # One events file per process, the resumed one written last
    interrupted_file, resumed_file = sorted((tb / "DCQN_1").glob("events.out.tfevents.*"), key=os.path.getmtime)
    steps: dict[str, np.ndarray] = {}
    for name, path in (("interrupted", interrupted_file), ("resumed", resumed_file)):
        events = EventAccumulator(str(path))
        events.Reload()
        scalars = events.Scalars("rollout/exploration_rate")
        steps[name] = np.array([event.step for event in scalars])
        # One curve over both processes; TensorBoard stores float32, hence the relative 1e-6
        expected = [EXPLORATION(1 - event.step / TOTAL) for event in scalars]
        np.testing.assert_allclose([event.value for event in scalars], expected, rtol=1e-6)
    assert steps["interrupted"].max() < CRASH_AT
    assert steps["resumed"].min() > LAST_SAVE and steps["resumed"].max() > CRASH_AT


if __name__ == "__main__":
    th.set_num_threads(1)
    phase, folder = sys.argv[1], Path(sys.argv[2])
    {"interrupted": interrupted_run, "resumed": resumed_run}[phase](folder)
