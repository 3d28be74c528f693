"""A script without an ``if __name__ == "__main__":`` guard builds a city's views in worker processes (issue 21).

The view-build workers are loky's (fork + exec of a fresh interpreter that does not import the parent's ``__main__``)
and never run the script: under multiprocessing's ``spawn`` each one ran the script again, built the env again and
waited (an hour) for the feature cache its parent was building.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import campusnav_env
from campusnav_env.features.parallel_build import default_workers

# README's city example as a user writes it: no main guard. The pixels encoder and 32 x 24 views keep it short; 300
# intersections are past MIN_NODES_FOR_WORKERS (256), so the views are built by one worker per core.
SCRIPT = """
import logging

import gymnasium as gym

import campusnav_env
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.rendering.street_view import RenderSettings

logging.basicConfig(level=logging.INFO)  # the parallel build says which processes build the views
env = gym.make(
    "CampusNavCity-v0", n_intersections=300, encoder="pixels", view_dim=16,
    view_build=ViewBuild(render_settings=RenderSettings(32, 24)),
)
observation, info = env.reset(seed=0)
print("intersections", env.unwrapped.graph.n_nodes, "views", observation["views"].shape)
"""

# The hang lasted the lock timeout (an hour); a working build takes about 30 s here on two busy cores
TIMEOUT = 300


@pytest.mark.skipif(default_workers() < 2, reason="one core: a 300-node map is built in this process, not in workers")
def test_a_script_without_a_main_guard_builds_a_city_in_workers_on_a_cold_cache(tmp_path: Path) -> None:
    script = tmp_path / "city.py"
    script.write_text(SCRIPT)
    cache = tmp_path / "cache"  # cold: nothing built yet
    env = {
        **os.environ,
        "CAMPUSNAV_CACHE": str(cache),
        # This checkout's package, whatever the venv has installed
        "PYTHONPATH": str(Path(campusnav_env.__file__).resolve().parents[1]),
        "OMP_NUM_THREADS": "1",
    }
    try:
        done = subprocess.run(
            [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=TIMEOUT
        )
    except subprocess.TimeoutExpired as e:
        stderr = e.stderr.decode(errors="replace") if isinstance(e.stderr, bytes) else e.stderr
        pytest.fail(f"the script did not finish within {TIMEOUT} s; its stderr ended with:\n{(stderr or '')[-3000:]}")
    assert done.returncode == 0, done.stderr[-3000:]
    assert "intersections 300 views (64,)" in done.stdout
    workers = min(default_workers(), 38)  # 300 nodes are 38 batches of 8
    assert f"building the views of 300 nodes in {workers} worker processes" in done.stderr  # the worker path
    assert "waiting for another process" not in done.stderr
    assert "300/300" in done.stderr  # the progress bar
    assert len(list(cache.glob("views-*.npz"))) == 1
