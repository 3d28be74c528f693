"""The experiment layer (``sb3_dcqn.campusnav``): one solved bar, one levers table, one train -> close -> recover loop.

The loop runs on the built-in campus with cheap ``pixels`` views and tiny networks: the first phase stops at the solved
bar or its step budget, each later closure is followed by its window (trained out when not stopping on recovery), and
the outcome holds everything the closure benchmarks and the command line report. The benchmarks keep no copy of the
bar, the levers' options or the loop.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.buffers import DictReplayBuffer
from stable_baselines3.common.envs import BitFlippingEnv

from campusnav_env import CampusNavEnv
from campusnav_env.closures import ClosureEvent
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.rendering.street_view import RenderSettings
from sb3_dcqn import DCQN, replay
from sb3_dcqn.adaptation_boost import AdaptationBoost
from sb3_dcqn.campusnav.experiments import ClosurePlan, train_with_closures
from sb3_dcqn.campusnav.levers import (
    DEMO_LEVERS,
    LEVERS,
    LeverSet,
    check_levers,
    lever_callbacks,
    lever_options,
    options_text,
    replay_variants,
    unusable_levers,
    usable_levers,
    with_levers,
)
from sb3_dcqn.campusnav.solved import SOLVED_SPL, SOLVED_SUCCESS, is_solved
from sb3_dcqn.replay import DCQNHerReplayBuffer, replay_buffer_class
from sb3_dcqn.zoo_entry import ZooEntry

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
# The scripts that train to the solved bar or run closures through the glue (scale.py and throughput.py: elsewhere)
GLUE_USERS = (
    "campusnav_runs.py",
    "closure_runs.py",
    "closures_one_at_a_time.py",
    "closures_eleven.py",
    "compare.py",
    "learning_speed.py",
    "paper_goals.py",
)


# The session's feature cache: the campus's views are rendered and encoded once, not once per module (conftest.py)
pytestmark = pytest.mark.usefixtures("shared_feature_cache")


def tiny_model(seed: int = 0) -> DCQN:
    env = CampusNavEnv(
        encoder="pixels",
        view_dim=16,
        max_steps=30,
        view_build=ViewBuild(render_settings=RenderSettings(width=64, height=48), progress=False),
    )
    return DCQN(
        "MultiInputPolicy",
        env,
        learning_starts=50,
        buffer_size=2_000,
        batch_size=16,
        train_freq=4,
        policy_kwargs={"net_arch": [16]},
        seed=seed,
        device="cpu",
    )


def test_the_solved_bar_is_success_099_and_spl_098_for_every_goal() -> None:
    assert (SOLVED_SUCCESS, SOLVED_SPL) == (0.99, 0.98)

    class Evaluation:
        def __init__(self) -> None:
            self.asked: tuple[float, float, bool] | None = None

        def meets(self, success: float, spl: float, every_goal: bool = False) -> bool:
            self.asked = (success, spl, every_goal)
            return True

    evaluation = Evaluation()
    assert is_solved(evaluation)  # type: ignore[arg-type]
    assert evaluation.asked == (0.99, 0.98, True)


def test_levers_combine_their_replay_variants_dcqn_and_env_options_in_order() -> None:
    # The adaptation boost is a callback, not a DCQN option
    assert set(LEVERS) == {
        *("revision", "blocked", "prioritized", "visible", "boost", "boost_on_revision", "route_memory"),
    }
    dcqn_options, env_options = lever_options(("revision", "blocked", "visible"))
    assert dcqn_options == {"blocked_action_target": True}
    assert env_options == {"visible_closures": True}
    assert replay_variants(("revision", "blocked", "prioritized", "boost_on_revision")) == ("revision", "prioritized")
    # The results files' option text (run records are matched on it): replay variants, DCQN options, the env's
    text = "replay variants revision, blocked_action_target=True, visible_closures=True"
    assert options_text(("revision", "blocked", "visible")) == text
    assert LeverSet("baseline").options_text() == "as shipped"
    entry = with_levers(ZooEntry(100, {"policy": "MultiInputPolicy"}, {"view_dim": 16}), ("prioritized", "visible"))
    assert entry.hyperparams == {
        "policy": "MultiInputPolicy",
        "replay_buffer_class": replay.PrioritizedDictReplayBuffer,
    }
    assert entry.env_kwargs == {"view_dim": 16, "visible_closures": True}
    with pytest.raises(KeyError, match="unknown lever 'moon'"):
        LeverSet("moon", ("moon",))


def test_the_boost_lever_adds_a_callback_and_no_dcqn_option() -> None:
    assert lever_options(("revision", "boost_on_revision")) == ({}, {})
    assert lever_callbacks(("revision", "prioritized")) == []
    (boost,) = lever_callbacks(("revision", "boost_on_revision"))
    assert isinstance(boost, AdaptationBoost) and boost.trigger == "revision"
    assert lever_callbacks(("boost",))[0] is not lever_callbacks(("boost",))[0]  # a fresh callback for each run
    text = "replay variants revision, callback AdaptationBoost(trigger='revision')"
    assert options_text(("revision", "boost_on_revision")) == text


def test_levers_are_added_to_the_entrys_replay_buffer_and_refused_where_they_do_not_combine() -> None:
    her = {"policy": "MultiInputPolicy", "replay_buffer_class": HerReplayBuffer}
    # Revision (and its boost) run with DCQN's HER buffer too; prioritized replay does not
    assert unusable_levers(("revision", "boost_on_revision", "blocked"), her) == {}
    usable, left_out = usable_levers((*DEMO_LEVERS, "prioritized"), her)
    assert usable == DEMO_LEVERS and list(left_out) == ["prioritized"]
    assert "every goal it is relabelled with" in left_out["prioritized"]
    assert usable_levers(("revision", "prioritized", "blocked"), {"policy": "MultiInputPolicy"}) == (
        ("revision", "prioritized", "blocked"),
        {},
    )
    lean = {**her, "replay_buffer_class": replay.LeanDictReplayBuffer}
    assert with_levers(ZooEntry(100, lean), ("prioritized",)).hyperparams["replay_buffer_class"] is (
        replay.LeanPrioritizedDictReplayBuffer
    )
    assert (
        "not replay_buffer_class=Own" in unusable_levers(("prioritized",), {"replay_buffer_class": Own})["prioritized"]
    )
    n_step = {"policy": "MultiInputPolicy", "n_steps": 8}
    assert (
        "n-step returns (nstep) does not combine with experience revision"
        in unusable_levers(("revision",), n_step)["revision"]
    )
    assert "blocked_action_target" in unusable_levers(("blocked",), n_step)["blocked"]
    with pytest.raises(
        ValueError, match=r"lever 'prioritized' \(prioritized replay\) cannot run here: hindsight relabelling"
    ):
        check_levers(("blocked", "visible", "boost", "prioritized"), her)
    with pytest.raises(ValueError, match="lever 'prioritized'"):
        with_levers(ZooEntry(100, her), ("prioritized",))
    assert with_levers(ZooEntry(100, her), ("revision",)).hyperparams["replay_buffer_class"] is (
        replay.RevisionHerReplayBuffer
    )
    assert with_levers(ZooEntry(100, her), ("blocked",)).hyperparams["blocked_action_target"] is True


class Own(DictReplayBuffer):
    """A user's own replay buffer class: DCQN builds it as given and adds no variant to it."""


def test_the_lever_rule_is_the_one_dcqn_applies() -> None:
    # Each lever builds a DCQN with hindsight relabelling exactly when the rule lets it run (SB3's BitFlippingEnv:
    # a small goal env)
    env = BitFlippingEnv(n_bits=4, max_steps=4)
    her = {"policy": "MultiInputPolicy", "replay_buffer_class": HerReplayBuffer, "learning_starts": 8}
    for name in LEVERS:
        entry = ZooEntry(100, her)
        if name in unusable_levers((name,), her):
            with pytest.raises(ValueError, match="stands for every goal"):  # the class DCQN would be given
                replay_buffer_class(*replay_variants((name,)), base="Her")
            continue
        levered = with_levers(entry, (name,))
        assert isinstance(levered.make_model(env).replay_buffer, DCQNHerReplayBuffer)
    model = DCQN(env=env, **her)
    with pytest.raises(ValueError, match="needs a replay buffer with experience revision"):
        model.learn(8, callback=lever_callbacks(("boost_on_revision",)))  # a boost on revisions needs them on
    revising = with_levers(ZooEntry(100, her), ("boost_on_revision",)).make_model(env)
    revising.learn(8, callback=lever_callbacks(("boost_on_revision",)))
    model.learn(8, callback=lever_callbacks(("boost",)))  # the episode-length trigger needs no buffer of its own


def test_closures_one_at_a_time_train_each_window_out_when_not_stopping_on_recovery() -> None:
    model = tiny_model()
    plan = ClosurePlan(
        later=[ClosureEvent(at=0, unit="step", close=((14, 15),)), ClosureEvent(at=0, unit="step", close=((3, 4),))]
    )
    outcome = train_with_closures(
        model, plan, budget=200, recovery_budget=120, eval_freq=100, stop_when_recovered=False, progress=False
    )
    first = outcome.closures.records[0].step
    assert first >= 100  # the first phase ran (its budget, or up to the solved bar)
    assert [record.closed for record in outcome.closures.records] == [((14, 15),), ((3, 4),)]
    # Each window trained out: the second closure 120 steps after the first, the run 120 steps after it
    assert outcome.closures.records[1].step - first == 120 and outcome.steps == first + 240
    assert len(outcome.recoveries) == 2 and outcome.before_closures() is not None
    assert outcome.evaluation.evaluations[-1].step == model.num_timesteps  # evaluated at the end of the last window
    assert 0 < outcome.first_phase_seconds < outcome.seconds
    assert len(outcome.progress.episode_rewards) == len(outcome.progress.episode_lengths) > 0


def test_the_first_phase_stops_at_its_training_seconds() -> None:
    outcome = train_with_closures(
        tiny_model(), ClosurePlan(), budget=5_000, recovery_budget=0, eval_freq=1_000, budget_seconds=0.5,
        progress=False,
    )  # fmt: skip
    assert 0 < outcome.steps < 5_000 and outcome.solved_at() is None


@pytest.mark.parametrize("script", GLUE_USERS)
def test_benchmarks_keep_no_copy_of_the_bar_the_levers_or_the_loop(script: str) -> None:
    text = (BENCHMARKS / script).read_text()
    assert not re.search(r"\b0\.9[89]\b", text), "the solved bar is sb3_dcqn.campusnav.solved's"
    for option in (
        "RevisionDictReplayBuffer",
        "blocked_action_target",
        "PrioritizedDictReplayBuffer",
        "visible_closures",
    ):
        assert option not in text, f"{option}: the levers table is sb3_dcqn.campusnav.levers'"
    assert "RoadClosureCallback(" not in text, "the closure loop is sb3_dcqn.campusnav.experiments'"
