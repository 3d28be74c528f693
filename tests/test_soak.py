"""Soak test: a million env steps of DCQN on a 1,000-intersection city with road closures, watching for leaks.

DCQN trains with the shipped CampusNavCity-v0 settings (``hyperparams/dcqn.yml``: lean replay buffer of 100k, 8-step
returns, the start curriculum, ...) on ``CampusNavCity-v0`` (1,000 intersections) seen through the cheap ``pixels``
encoder. Every ``SOAK_CLOSURE_EVERY`` steps
the closures rotate: the roads closed last time reopen and ten others close (a new random draw that keeps the goal
reachable, so the map stays solvable). A callback samples the process every ``SOAK_WINDOW`` steps: resident memory
(``VmRSS``), the time per env step over the window (wall clock, and this process's CPU time), open file descriptors
and the files in a temp dir of the test's own (``TMPDIR``). Once the replay buffer is full, nothing may grow:

- resident memory at the end within 5 % of the first sample after the buffer filled;
- time per step flat: the median CPU time per step of the last windows within 1.5x the median of the first windows
  after the fill (CPU time of this process and medians, so that other work on a shared machine does not decide; the
  wall-clock time is reported beside it);
- no more open file descriptors and no more temp files at the end than at the first sample after the fill.

Marked slow (not in the default selection); the lead runs the full million::

    pytest -m slow tests/test_soak.py -s

Shorter runs, e.g. to check the test itself: ``SOAK_STEPS=60000 SOAK_CLOSURE_EVERY=10000 SOAK_WINDOW=5000
SOAK_BUFFER_SIZE=20000`` (the buffer must fill well before the end). ``SOAK_REPORT=path`` also writes the summary
table to that file. Linux only (it reads ``/proc/self``).
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import pytest
from stable_baselines3.common.callbacks import BaseCallback, CallbackList

from campusnav_env.callbacks import RoadClosureCallback
from campusnav_env.closures import ClosureEvent
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.rendering.street_view import RenderSettings
from sb3_dcqn import DCQN
from sb3_dcqn.zoo_entry import load_zoo_entry
from sb3_dcqn.zoo_files import default_hyperparams_path

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="the soak test reads /proc/self (Linux)"),
]

STEPS = int(os.environ.get("SOAK_STEPS", 1_000_000))
CLOSURE_EVERY = int(os.environ.get("SOAK_CLOSURE_EVERY", 50_000))
WINDOW = int(os.environ.get("SOAK_WINDOW", 10_000))
# Default: the CampusNavCity-v0 entry's buffer_size (100k); smaller only to run the test short
BUFFER_SIZE = int(os.environ["SOAK_BUFFER_SIZE"]) if os.environ.get("SOAK_BUFFER_SIZE") else None
REPORT = os.environ.get("SOAK_REPORT")

ENV_ID = "CampusNavCity-v0"
INTERSECTIONS = 1_000
ROADS_PER_CLOSURE = 10
RSS_GROWTH_LIMIT = 0.05
STEP_TIME_RATIO_LIMIT = 1.5
# Windows on each side of the step-time comparison (fewer when the run is short)
COMPARED_WINDOWS = 3


def make_city_env() -> gym.Env:
    """``CampusNavCity-v0`` (1,000 intersections) with its entry's env_kwargs (view_dim 64) and cheap pixel views."""
    entry = load_zoo_entry(default_hyperparams_path(), ENV_ID)
    cheap = ViewBuild.of(entry.env_kwargs.get("view_build"), render_settings=RenderSettings(64, 48), progress=False)
    kwargs = dict(entry.env_kwargs, encoder="pixels", view_build=cheap)
    return gym.make(ENV_ID, n_intersections=INTERSECTIONS, **kwargs)


def rotating_closures(total_steps: int, every: int) -> list[ClosureEvent]:
    """Every ``every`` steps: reopen the roads closed last time, then close a new random draw of roads."""
    events = []
    for k, at in enumerate(range(every, total_steps, every), start=1):
        if k > 1:
            events.append(ClosureEvent(at=at, unit="step", reopen="all"))
        events.append(ClosureEvent(at=at, unit="step", close_random=ROADS_PER_CLOSURE, seed=k))
    return events


def resident_kib() -> int:
    """Resident memory of this process (``VmRSS``, KiB)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError("/proc/self/status has no VmRSS line")


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def files_under(folder: Path) -> int:
    return sum(len(files) for _, _, files in os.walk(folder))


@dataclass(frozen=True)
class ResourceSample:
    """The process at the end of one window of env steps."""

    step: int
    seconds_per_step: float
    cpu_seconds_per_step: float
    rss_kib: int
    open_fds: int
    temp_files: int
    closed_roads: int


class ResourceMonitor(BaseCallback):
    """
    Sample resident memory, time per env step, open file descriptors and temp files every ``window`` env steps.

    :param window: Env steps per sample
    :param temp_dir: The folder whose files are counted (the process's ``TMPDIR``)
    :param verbose: 1 prints a line per sample
    """

    def __init__(self, window: int, temp_dir: Path, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.window = window
        self.temp_dir = temp_dir
        self.samples: list[ResourceSample] = []
        self._window_start = (0.0, 0.0)

    def _on_training_start(self) -> None:
        self._window_start = (time.perf_counter(), time.process_time())

    def _on_step(self) -> bool:
        if self.num_timesteps % self.window == 0:
            (wall, cpu), started = (time.perf_counter(), time.process_time()), self._window_start
            sample = ResourceSample(
                step=self.num_timesteps,
                seconds_per_step=(wall - started[0]) / self.window,
                cpu_seconds_per_step=(cpu - started[1]) / self.window,
                rss_kib=resident_kib(),
                open_fds=open_fds(),
                temp_files=files_under(self.temp_dir),
                closed_roads=len(self.training_env.get_attr("closed_roads")[0]),
            )
            self.samples.append(sample)
            if self.verbose >= 1:
                print(format_row(sample), flush=True)
            self._window_start = (time.perf_counter(), time.process_time())  # sampling is not part of the next window
        return True


TABLE_HEADER = f"{'step':>9} {'us/step':>8} {'CPU us':>7} {'RSS MiB':>8} {'fds':>4} {'temp files':>10} {'closed':>6}"


def format_row(sample: ResourceSample) -> str:
    return (
        f"{sample.step:>9} {sample.seconds_per_step * 1e6:>8.0f} {sample.cpu_seconds_per_step * 1e6:>7.0f} "
        f"{sample.rss_kib / 1024:>8.1f} "
        f"{sample.open_fds:>4} {sample.temp_files:>10} {sample.closed_roads:>6}"
    )


def summary(samples: list[ResourceSample], buffer_size: int, verdicts: list[str]) -> str:
    lines = [
        f"DCQN soak: {STEPS} env steps, {INTERSECTIONS} intersections, buffer {buffer_size}, "
        f"{ROADS_PER_CLOSURE} roads rotated every {CLOSURE_EVERY} steps, windows of {WINDOW} steps",
        TABLE_HEADER,
        *(format_row(s) + ("  (buffer full)" if s.step - WINDOW < buffer_size <= s.step else "") for s in samples),
        *verdicts,
    ]
    return "\n".join(lines)


def test_a_long_run_with_closures_grows_no_memory_time_files_or_descriptors(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    temp_dir = tmp_path / "tmpdir"
    temp_dir.mkdir()
    monkeypatch.setenv("TMPDIR", str(temp_dir))
    monkeypatch.setattr(tempfile, "tempdir", str(temp_dir))  # gettempdir() caches its first answer

    entry = load_zoo_entry(default_hyperparams_path(), ENV_ID)
    hyperparams = dict(entry.hyperparams)
    if BUFFER_SIZE is not None:
        hyperparams["buffer_size"] = BUFFER_SIZE
    buffer_size = hyperparams["buffer_size"]
    steps_after_fill = STEPS - buffer_size
    if steps_after_fill < 2 * WINDOW:
        pytest.fail(f"SOAK_STEPS={STEPS} leaves fewer than two windows of {WINDOW} steps after the buffer fills")

    model = DCQN(env=make_city_env(), seed=0, verbose=0, **hyperparams)
    schedule = rotating_closures(STEPS, CLOSURE_EVERY)
    closures = RoadClosureCallback(schedule)
    monitor = ResourceMonitor(WINDOW, temp_dir, verbose=1)
    print("\n" + TABLE_HEADER, flush=True)
    model.learn(STEPS, callback=CallbackList([*entry.make_callbacks(), closures, monitor]))

    # Samples whose window lies wholly after the buffer filled (the buffer's pages are touched as it fills)
    filled = [s for s in monitor.samples if s.step - WINDOW >= buffer_size]
    first, last = filled[0], filled[-1]
    compared = max(1, min(COMPARED_WINDOWS, len(filled) // 2))
    early = statistics.median(s.cpu_seconds_per_step for s in filled[:compared])
    late = statistics.median(s.cpu_seconds_per_step for s in filled[-compared:])
    early_wall = statistics.median(s.seconds_per_step for s in filled[:compared])
    late_wall = statistics.median(s.seconds_per_step for s in filled[-compared:])
    rss_growth = last.rss_kib / first.rss_kib - 1
    verdicts = [
        f"RSS after the fill: {first.rss_kib / 1024:.1f} -> {last.rss_kib / 1024:.1f} MiB ({rss_growth:+.1%}, "
        f"limit +{RSS_GROWTH_LIMIT:.0%})",
        f"CPU time per step, median of the first {compared} windows after the fill {early * 1e6:.0f} us, of the "
        f"last {compared} {late * 1e6:.0f} us ({late / early:.2f}x, limit {STEP_TIME_RATIO_LIMIT}x); wall clock "
        f"{early_wall * 1e6:.0f} -> {late_wall * 1e6:.0f} us ({late_wall / early_wall:.2f}x)",
        f"open fds {first.open_fds} -> {last.open_fds}, temp files {first.temp_files} -> {last.temp_files}",
        f"closure events {len(closures.records)}, refused {sum(len(r.refused) for r in closures.records)}",
    ]
    report = summary(monitor.samples, buffer_size, verdicts)
    print(report, flush=True)
    if REPORT:
        Path(REPORT).write_text(report + "\n")

    assert len(closures.records) == len(schedule), report
    assert not any(record.refused for record in closures.records), report
    assert rss_growth < RSS_GROWTH_LIMIT, report
    assert late <= STEP_TIME_RATIO_LIMIT * early, report
    assert last.open_fds <= first.open_fds, report
    assert last.temp_files <= first.temp_files, report
