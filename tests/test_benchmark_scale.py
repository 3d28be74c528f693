"""benchmarks/scale.py and its five question scripts run and write their tables and picture (smoke runs: the figures
themselves are not asserted)."""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _quick_run(tmp_path: Path, script: str) -> tuple[str, list[dict]]:
    """Run a smoke run (views encoded into a fresh cache in tmp_path); return its results file and all records."""
    out, runs = tmp_path / "scale.md", tmp_path / "runs.jsonl"
    env = {**os.environ, "CAMPUSNAV_CACHE": str(tmp_path / "campusnav-cache")}
    command = [sys.executable, str(BENCHMARKS / script), "--quick", "--out", str(out), "--runs-file", str(runs)]
    subprocess.run(command, check=True, timeout=600, env=env, cwd=tmp_path)
    return out.read_text(), [json.loads(line) for line in runs.read_text().splitlines()]


def test_scale_quick_run_writes_its_tables_and_picture(tmp_path: Path) -> None:
    text, records = _quick_run(tmp_path, "scale.py")
    # Every stage of the smoke run was recorded, once
    stages = sorted((r["stage"], r["size"]) for r in records)
    assert stages == sorted(
        [("buffer", 0), ("vecenv", 30)] + [(stage, n) for stage in ("build", "fit", "train") for n in (30, 60)]
    )
    assert "| intersections | states | encoder, views | map (s) | 3D world (s) | render (ms/node) |" in text
    assert "| intersections | features | budget (s) | solved | training time to threshold (s) | env steps |" in text
    shipped = "DictReplayBuffer (shipped)"
    assert f"| array (B per transition) | {shipped}, view_dim 64 | {shipped}, view_dim 1280 |" in text
    assert "| view_dim | features: B/transition | 50,000 transitions (MB) | indices: B/transition |" in text
    assert "| vector env | envs | env steps/s (all envs) | vs DummyVecEnv, 1 env |" in text
    assert "| part of one env step | us per call |" in text
    assert "| intersections | cold build, EfficientNet (s) | of which render / encode / 3D world |" in text
    # The feature transform is measured as shipped: no "before the fix" columns without records of the code before
    assert "| intersections (views x features) | after: fit + transform (s) | after: peak memory (MB) |" in text
    assert "before: fit + transform" not in text
    # The large map's EfficientNet cost is extrapolated, and the results say so
    assert "extrapolated from 2 nodes" in text
    assert "Machine: " in text and "Command: `python benchmarks/scale.py --quick --out" in text
    assert (tmp_path / "scale.png").stat().st_size > 0


def test_each_question_script_runs_only_its_own_stages(monkeypatch) -> None:
    monkeypatch.syspath_prepend(str(BENCHMARKS.parent))
    from benchmarks import scale
    from benchmarks.scale_common import Plan

    plan = Plan(sizes=(101, 300), budgets={}, eval_freq={}, max_steps={})
    everything = [(stage, size) for stage, size, _, _ in scale.planned_stages(plan)]
    assert everything == [("buffer", 0), ("build", 101), ("build", 300), ("fit", 101), ("fit", 300),
                          ("vecenv", 101), ("train", 101), ("train", 300)]  # fmt: skip
    for question in ("scale_replay", "scale_world_build", "scale_feature_transform", "scale_vec_env", "scale_training"):
        stage = importlib.import_module(f"benchmarks.{question}").STAGE
        picked = scale.planned_stages(plan, (stage,))
        assert picked and {name for name, _, _, _ in picked} == {stage}
