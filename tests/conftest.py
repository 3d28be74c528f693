"""Shared test fixtures: one torch thread (two cores are not oversubscribed) and nothing left in the temp dir."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch


@pytest.fixture(autouse=True)
def _single_torch_thread() -> None:
    torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def _sb3_logs_in_tmp_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # learn() without a TensorBoard folder configures SB3's logger with $SB3_LOGDIR, else a new SB3-<date> folder in
    # the system temp dir (stable_baselines3.common.logger.configure); subprocesses inherit the variable
    monkeypatch.setenv("SB3_LOGDIR", str(tmp_path / "sb3-logs"))


@pytest.fixture(autouse=True, scope="session")
def _library_caches_in_pytest_temp(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    # torch's first optimizer step imports torch._dynamo, which creates <temp dir>/torchinductor_<user>; matplotlib
    # (imported by the RL Zoo) writes its font cache to ~/.cache/matplotlib. Both move unless set by the caller.
    # SB3_LOGDIR here too: module-scoped fixtures (benchmark runs, the resume test's subprocesses) are set up before
    # the per-test folder above exists, and each learn() of theirs would leave an SB3-<date> folder in the temp dir.
    caches = {"TORCHINDUCTOR_CACHE_DIR": "torchinductor", "MPLCONFIGDIR": "matplotlib", "SB3_LOGDIR": "sb3-logs"}
    with pytest.MonkeyPatch.context() as patch:
        for variable, name in caches.items():
            if variable not in os.environ:
                patch.setenv(variable, str(tmp_path_factory.mktemp(name)))
        yield


@pytest.fixture(scope="session")
def shared_cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One feature cache for the whole test session, in pytest's temp folder (never the user's ``~/.cache/campusnav``,
    whose state no test may depend on): the views of a world, render settings and encoder are rendered and encoded by
    the first test that asks and read by every other (the cache is file-locked, so subprocesses share it too). Tests
    of the cache itself, and benchmarks that time a cold build, keep a folder of their own."""
    return tmp_path_factory.mktemp("campusnav-cache")


@pytest.fixture(scope="module")
def shared_feature_cache(shared_cache_dir: Path) -> Iterator[Path]:
    """``$CAMPUSNAV_CACHE`` set to the session's shared feature cache for a module (``pytest.mark.usefixtures``, or
    an argument of the module fixtures that build envs or start processes that do); the caller's value after it."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("CAMPUSNAV_CACHE", str(shared_cache_dir))
        yield shared_cache_dir


@pytest.fixture
def conf(tmp_path: Path) -> Path:
    """The small entry of ``dcqn-campusnav``'s run tests (``cli_runs_support.TINY_CONF``), as a file."""
    from cli_runs_support import TINY_CONF

    path = tmp_path / "tiny.yml"
    path.write_text(TINY_CONF)
    return path
