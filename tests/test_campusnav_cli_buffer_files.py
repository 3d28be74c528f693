"""Replay buffer files as large as what the buffer stores (:mod:`sb3_dcqn.campusnav.buffer_files`).

A buffer of every kind DCQN trains with (plain, dict, with revision, prioritized, lean, hindsight relabelling) is
written compactly after a few steps, read back with SB3's ``load_replay_buffer``, and compared with the live buffer
attribute by attribute: the arrays bit for bit, sets as sets, everything else as it pickles. The file is a small
share of SB3's own.
"""

from __future__ import annotations

import io
import pickle
from typing import Any

import numpy as np
import pytest

from sb3_dcqn import DCQN
from sb3_dcqn.campusnav.buffer_files import dump_compact_buffer
from sb3_dcqn.replay import replay_buffer_class


def assert_same(live: Any, loaded: Any, where: str) -> None:
    if isinstance(live, np.ndarray):
        assert isinstance(loaded, np.ndarray) and loaded.dtype == live.dtype, where
        assert loaded.shape == live.shape and np.array_equal(loaded, live, equal_nan=live.dtype.kind in "fc"), where
    elif isinstance(live, dict):
        assert isinstance(loaded, dict) and loaded.keys() == live.keys(), where
        for key in live:
            assert_same(live[key], loaded[key], f"{where}[{key!r}]")
    elif isinstance(live, (set, frozenset)):  # a set's pickle follows its iteration order, which its history sets
        assert type(loaded) is type(live) and loaded == live, where
    elif hasattr(live, "__dict__") and not isinstance(live, type):
        assert type(loaded) is type(live), where
        for key, value in vars(live).items():
            if key != "env":  # SB3's HER buffer does not pickle its env
                assert_same(value, getattr(loaded, key), f"{where}.{key}")
    else:
        assert pickle.dumps(loaded) == pickle.dumps(live), where


def cartpole_model(variants: tuple[str, ...]) -> DCQN:
    buffer_class = replay_buffer_class(*variants, base="Box")
    return DCQN(
        "MlpPolicy", "CartPole-v1", buffer_size=5_000, learning_starts=50, batch_size=16,
        replay_buffer_class=buffer_class, policy_kwargs={"net_arch": [8]}, seed=0,
    )  # fmt: skip


@pytest.mark.parametrize("variants", [(), ("prioritized",), ("nstep",), ("revision",)])
def test_a_compact_buffer_file_loads_back_as_the_live_buffer(tmp_path: Any, variants: tuple[str, ...]) -> None:
    model = cartpole_model(variants)
    model.learn(300)
    data = io.BytesIO()
    dump_compact_buffer(model.replay_buffer, data)
    path = tmp_path / "buffer.pkl"
    path.write_bytes(data.getvalue())
    sb3 = tmp_path / "sb3.pkl"
    model.save_replay_buffer(sb3)
    assert path.stat().st_size < sb3.stat().st_size / 5  # 300 of 5,000 slots stored
    live = model.replay_buffer
    fresh = cartpole_model(variants)
    fresh.load_replay_buffer(path)
    assert_same(live, fresh.replay_buffer, "buffer")
    fresh.learn(100, reset_num_timesteps=False)  # and training goes on with it
    assert fresh.replay_buffer is not None and fresh.replay_buffer.size() == live.size() + 100


@pytest.mark.usefixtures("shared_feature_cache")
# The lean buffer stores each observation once already: its file is no larger than SB3 writes it
@pytest.mark.parametrize(("variants", "share"), [((), 1 / 20), (("lean",), 1.0), (("revision", "prioritized"), 1 / 20)])
def test_a_campusnav_dict_buffer_loads_back_as_the_live_buffer(variants: tuple[str, ...], share: float) -> None:
    from campusnav_env import CampusNavEnv
    from campusnav_env.features.view_build import ViewBuild
    from campusnav_env.rendering.street_view import RenderSettings

    env = CampusNavEnv(
        encoder="pixels", view_build=ViewBuild(render_settings=RenderSettings(width=64, height=48), progress=False)
    )
    model = DCQN(
        "MultiInputPolicy", env, buffer_size=20_000, learning_starts=50, batch_size=16,
        replay_buffer_class=replay_buffer_class(*variants), policy_kwargs={"net_arch": [8]}, seed=0,
    )  # fmt: skip
    model.learn(300)
    data = io.BytesIO()
    dump_compact_buffer(model.replay_buffer, data)
    sb3 = io.BytesIO()
    model.save_replay_buffer(sb3)
    assert len(data.getvalue()) <= share * len(sb3.getvalue())  # 300 of 20,000 slots, CampusNav's views repeat
    assert_same(model.replay_buffer, pickle.loads(data.getvalue()), "buffer")


def test_a_full_buffer_is_written_whole_and_loads_back(tmp_path: Any) -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", buffer_size=200, learning_starts=50, policy_kwargs={"net_arch": [8]})
    model.learn(500)
    assert model.replay_buffer is not None and model.replay_buffer.full
    data = io.BytesIO()
    dump_compact_buffer(model.replay_buffer, data)
    assert_same(model.replay_buffer, pickle.loads(data.getvalue()), "buffer")


@pytest.mark.parametrize("variants", [(), ("revision",)])
def test_an_empty_buffer_is_written_and_loads_back(variants: tuple[str, ...]) -> None:
    # A run that stored no transition (readapt of a model saved without its buffer, recovered at once) saves it too
    model = cartpole_model(variants)
    assert model.replay_buffer is not None and model.replay_buffer.size() == 0
    data = io.BytesIO()
    dump_compact_buffer(model.replay_buffer, data)
    assert_same(model.replay_buffer, pickle.loads(data.getvalue()), "buffer")
