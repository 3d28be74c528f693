"""The memory's evidence about itself: whether the places its remembered moves predict are the places it then sees.

A remembered move is a prediction: from this place, this slot leads there (or nowhere: a closed road). Each time the
agent makes a move the memory knows, the memory scores it: a **hit** where the place recognised after the move is the
one predicted (for a stochastic move, one of the ends it has led to before), a **miss** where it is another place,
or a picture it is unsure of. :class:`PredictionRecord` keeps the latest :data:`PREDICTION_WINDOW` scores.

A deterministic world the memory recognises well predicts almost every move (a closure is one miss per road side);
a world whose pictures it cannot tell apart, or whose roads lead to different places by chance before it has counted
them, does not. Where the share of hits over the window falls below :data:`STAND_ASIDE_BELOW` the memory **stands
aside**: it neither routes, nor explores, nor revises the replay buffer (the critics act alone, on data the memory
has not touched), but it goes on remembering and scoring its predictions. Where the share is back above
:data:`SPEAK_AGAIN_ABOVE` it speaks again (the gap between the two bars keeps it from flickering). Before
:data:`MIN_PREDICTIONS` scores nothing is judged. Model-based RL's rule (Dyna, PETS, MBPO): a model is used where its
predictions come true.

Why these bars: a route of ``h`` hops arrives as planned with about ``accuracy ** h``; on CampusNav's routes (a median
of 8-10 hops) 0.8 per move is under one route in five as planned, and a route that goes wrong costs the critics' steps
to recover from a wrong place; every world the memory was measured to help in predicts above 0.95 (the benchmarks'
``prediction_accuracy`` column).

Between the bars the memory's routes arrive, but not always as planned: below :data:`TRIAL_BELOW` they are **on
trial** against the critics' own (:class:`EpisodeTrial`). A share of the training episodes (:data:`TRIAL_SHARE`) is
driven by whichever side does not lead, and the side whose latest episodes were shorter leads: it drives the other
training episodes and every greedy (evaluation) step. Episodes are the outcome a user measures (a failed episode
counts the steps it took before the time limit), and both sides' episodes start where the env starts them, so their
mean lengths compare the two ways of driving on the same tasks: a harder varied world whose places split is driven
by the critics once they have learned it, while a world the memory predicts well never puts it on trial. Two rules
keep the trial to its evidence:

- both sides are judged over the same, latest stretch of training (the latest :data:`TRIAL_WINDOW` episodes, whoever
  drove them): the critics learn as they go, and their episodes from thousands of steps ago would speak for critics
  that are gone (a window per side would reach four times further back for the side that drives a quarter);
- a trial the critics lead goes on whatever the memory's predictions do: only the memory's own shorter episodes win
  the lead back (predictions that come true do not make routes short: a place split in two predicts well and plans
  detours). Standing aside ends it.
"""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = [
    "MIN_PREDICTIONS",
    "PREDICTION_WINDOW",
    "SPEAK_AGAIN_ABOVE",
    "STAND_ASIDE_BELOW",
    "TRIAL_BELOW",
    "EpisodeTrial",
    "PredictionRecord",
]

PREDICTION_WINDOW = 256  # the latest scored predictions the memory is judged on
MIN_PREDICTIONS = 64  # fewer scores than this: nothing judged yet (the memory speaks)
STAND_ASIDE_BELOW = 0.8  # the share of hits below which the memory stands aside
SPEAK_AGAIN_ABOVE = 0.9  # the share of hits above which it speaks again
TRIAL_BELOW = 0.95  # the share of hits below which its routes are on trial against the critics'
TRIAL_SHARE = 0.25  # the share of a trial's training episodes the side not leading drives
TRIAL_WINDOW = 200  # the latest episodes a trial judges, both sides' together
TRIAL_MIN_EPISODES = 20  # fewer episodes of either side: the memory leads


class PredictionRecord:
    """
    The latest scores of the memory's predictions and whether it stands aside (see the module docstring).

    :param window: Scores kept (the latest)
    """

    def __init__(self, window: int = PREDICTION_WINDOW) -> None:
        if window < MIN_PREDICTIONS:
            raise ValueError(f"the prediction window must hold at least {MIN_PREDICTIONS} scores, got {window}")
        self._scores: deque[bool] = deque(maxlen=window)
        self._hits = 0  # hits among the kept scores
        self.scored = 0  # every score so far
        self.standing_aside = False
        self.changes = 0  # times it stood aside or spoke again

    def __len__(self) -> int:
        """Scores kept."""
        return len(self._scores)

    @property
    def accuracy(self) -> float:
        """The share of hits among the kept scores (NaN before any)."""
        return self._hits / len(self._scores) if self._scores else float("nan")

    @property
    def on_trial(self) -> bool:
        """Whether the memory's routes are on trial: judged, speaking, and below :data:`TRIAL_BELOW`."""
        return len(self._scores) >= MIN_PREDICTIONS and not self.standing_aside and self.accuracy < TRIAL_BELOW

    def score(self, hits: np.ndarray) -> bool:
        """
        Add scores (one per predicted move, in order: ``True`` a hit).

        :return: whether the memory now stands aside or speaks again (a change)
        """
        for hit in np.asarray(hits, dtype=bool).reshape(-1).tolist():
            if len(self._scores) == self._scores.maxlen:
                self._hits -= self._scores[0]
            self._scores.append(hit)
            self._hits += hit
        self.scored += int(np.asarray(hits).size)
        if len(self._scores) < MIN_PREDICTIONS:
            return False
        accuracy = self.accuracy
        stands = accuracy <= SPEAK_AGAIN_ABOVE if self.standing_aside else accuracy < STAND_ASIDE_BELOW
        if stands == self.standing_aside:
            return False
        self.standing_aside = stands
        self.changes += 1
        return True


class EpisodeTrial:
    """
    Who drives while the memory's routes are on trial: the memory or the critics, judged by the lengths of the latest
    :data:`TRIAL_WINDOW` training episodes, each side on those it drove (see the module docstring). The lead changes
    only where the leader's mean is longer than the other's by more than their standard error: a gap within the noise
    changes nothing (where the two sides are close, the lead still changes now and then, judged again at every
    episode's end).

    :param n_envs: The training envs (each episode's driver is drawn when it starts)
    """

    _judged_since = False  # trials pickled before it was kept: judged at their next step

    def __init__(self, n_envs: int) -> None:
        self.critics_lead = False
        self.changes = 0  # times the lead changed
        self._episodes: deque[tuple[bool, int]] = deque(maxlen=TRIAL_WINDOW)  # (the critics drove it, its length)
        self._critics_drive = np.zeros(n_envs, dtype=bool)  # per env: the critics drive its episode
        self._steps = np.zeros(n_envs, dtype=np.int64)  # per env: steps of its episode so far
        self._judged_since = False  # on trial since the last judgement (no episode ended since: nothing new to judge)

    def __setstate__(self, state: dict) -> None:
        # A trial pickled with a window per side: its episodes, the memory's then the critics', the latest kept
        if "_lengths" in state:
            kept = state.pop("_lengths")
            state["_episodes"] = deque(
                ((side, int(length)) for side in (False, True) for length in kept[side]), maxlen=TRIAL_WINDOW
            )
        self.__dict__.update(state)

    @property
    def n_envs(self) -> int:
        return int(self._critics_drive.size)

    def critics_drive(self) -> np.ndarray:
        """Per training env: whether the critics drive its episode."""
        return self._critics_drive.copy()

    def mean_steps(self, critics: bool) -> float:
        """The mean length of the side's episodes among the latest (NaN before any)."""
        lengths = self._lengths(critics)
        return float(lengths.mean()) if lengths.size else float("nan")

    def episodes(self, critics: bool) -> int:
        """The side's episodes among the latest."""
        return int(self._lengths(critics).size)

    def _lengths(self, critics: bool) -> np.ndarray:
        return np.array([length for side, length in self._episodes if side == critics], dtype=np.float64)

    def step(self, dones: np.ndarray, on_trial: bool, draws: np.ndarray | None) -> bool:
        """
        One training step of every env: while on trial, each finished episode's length is recorded for the side that
        drove it and the env's next episode is given a driver by ``draws`` (uniform in [0, 1), one per env); off
        trial, the memory drives the next episode.

        :return: whether the lead changed
        """
        self._steps += 1
        ended = np.flatnonzero(np.asarray(dones, dtype=bool).reshape(-1))
        for env in ended.tolist():
            if on_trial and draws is not None:
                self._episodes.append((bool(self._critics_drive[env]), int(self._steps[env])))
                self._critics_drive[env] = (float(draws[env]) < TRIAL_SHARE) != self.critics_lead
            else:
                self._critics_drive[env] = False
            self._steps[env] = 0
        if not on_trial:
            lead = False
        elif ended.size or not self._judged_since:  # the lengths change only where an episode ended (or it begins)
            lead = self._judged()
        else:
            lead = self.critics_lead  # nothing new to judge: the same lengths give the same lead
        self._judged_since = on_trial
        if lead == self.critics_lead:
            return False
        self.critics_lead = lead
        self.changes += 1
        return True

    def _judged(self) -> bool:
        """Whether the critics lead now: their episodes shorter by more than the standard error (the lead kept else)."""
        memory, critics = self._lengths(False), self._lengths(True)
        if min(len(memory), len(critics)) < TRIAL_MIN_EPISODES:
            return self.critics_lead
        error = np.sqrt(memory.var(ddof=1) / len(memory) + critics.var(ddof=1) / len(critics))
        gap = memory.mean() - critics.mean()  # positive: the critics' episodes are shorter
        if gap > error:
            return True
        if gap < -error:
            return False
        return self.critics_lead
