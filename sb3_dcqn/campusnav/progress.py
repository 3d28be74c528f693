"""A tqdm progress bar for SB3 training that also keeps every training episode's return and length.

Used by the ``dcqn-campusnav`` command line (:mod:`sb3_dcqn.campusnav.cli`); it works with any SB3 algorithm and any
``VecEnv`` whose envs are wrapped in a ``Monitor`` (as ``make_vec_env`` does). Unlike SB3's ``progress_bar=True`` it
needs only tqdm (no rich), writes to stderr, names the training phase, shows the episodes so far and, given a
:class:`~campusnav_env.callbacks.RouteEvaluationCallback`, the latest route evaluation's success rate and SPL::

    progress = TqdmProgress(evaluation)
    progress.phase = "train"
    model.learn(30_000, callback=[closures, progress])
    rewards, lengths = progress.episode_rewards, progress.episode_lengths

A bar ends on what happened, never on a score the model has trained past: :attr:`TqdmProgress.ending` (e.g. "solved
at 9,000 steps"), else the latest evaluation once training has ended (pass the bar after the evaluation, or after the
closure callback that holds it, so that the evaluation at the end of training comes first). A phase that stopped
before its budget (solved, recovered) ends full, its budget named, so that it does not read as a crash.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any, TextIO

from stable_baselines3.common.callbacks import BaseCallback
from tqdm import tqdm

from campusnav_env.callbacks import RouteEvaluationCallback

__all__ = ["TqdmProgress"]


class TqdmProgress(BaseCallback):
    """
    Progress bar over the steps of each ``learn`` call, and a record of the training episodes across calls.

    One instance serves several ``learn`` calls (set :attr:`phase` before each): the bar restarts, the episode record
    goes on, in the order the episodes ended (all envs together, as the closure callbacks count them).

    :param evaluation: Route evaluation whose latest success rate and SPL the bar shows (optional)
    :param disable: Show no bar (the episodes are still recorded)
    :param file: Where the bar goes (default: ``sys.stderr``)
    :ivar ending: What happened, in a line, asked for when training ends (default: the latest evaluation's scores)
    """

    def __init__(
        self, evaluation: RouteEvaluationCallback | None = None, disable: bool = False, file: TextIO | None = None
    ) -> None:
        super().__init__()
        self.evaluation = evaluation
        self.disable = disable
        self.file = file
        self.phase = "train"
        self.ending: Callable[[], str] | None = None
        self.episode_rewards: list[float] = []
        self.episode_lengths: list[int] = []
        self._bar: Any = None
        self._shown: tuple[int, int] | None = None

    def _on_training_start(self) -> None:
        total = max(0, int(self.locals["total_timesteps"]) - self.model.num_timesteps)
        self._bar = tqdm(
            total=total,
            desc=self.phase,
            unit="step",
            file=self.file if self.file is not None else sys.stderr,
            disable=self.disable,
            dynamic_ncols=True,
        )
        self._shown = None  # show the current numbers at once

    def _on_step(self) -> bool:
        for info in self.locals.get("infos", ()):
            episode = info.get("episode")
            if episode is not None:  # added by Monitor on an episode's last step
                self.episode_rewards.append(float(episode["r"]))
                self.episode_lengths.append(int(episode["l"]))
        if self._bar is not None:
            self._bar.update(self.training_env.num_envs)
            evaluations = [] if self.evaluation is None else self.evaluation.evaluations
            shown = (len(self.episode_rewards), len(evaluations))
            if shown != self._shown:  # new episodes or a new evaluation
                self._shown = shown
                postfix: dict[str, Any] = {"episodes": shown[0]}
                if evaluations:
                    postfix["success"] = f"{evaluations[-1].success_rate:.3f}"
                    postfix["SPL"] = f"{evaluations[-1].spl:.3f}"
                self._bar.set_postfix(postfix, refresh=False)
        return True

    def last_words(self) -> str:
        """The line the bar ends on: :attr:`ending`, else the episodes and the latest evaluation's scores."""
        if self.ending is not None:
            return self.ending()
        said = f"{len(self.episode_rewards)} episodes"
        if self.evaluation is not None and self.evaluation.evaluations:
            last = self.evaluation.evaluations[-1]
            said += f"; at {last.step:,} steps: success {last.success_rate:.3f}, SPL {last.spl:.3f}"
        return said

    def _on_training_end(self) -> None:
        bar, self._bar = self._bar, None
        if bar is None:
            return
        words = self.last_words()
        if bar.total and bar.n < bar.total:  # stopped before its budget: full, the budget named
            words += f" (budget {bar.total:,} steps)"
            bar.total = bar.n
        bar.set_postfix_str(words, refresh=False)
        bar.close()
