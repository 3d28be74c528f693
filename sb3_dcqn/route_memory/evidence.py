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
"""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["MIN_PREDICTIONS", "PREDICTION_WINDOW", "SPEAK_AGAIN_ABOVE", "STAND_ASIDE_BELOW", "PredictionRecord"]

PREDICTION_WINDOW = 256  # the latest scored predictions the memory is judged on
MIN_PREDICTIONS = 64  # fewer scores than this: nothing judged yet (the memory speaks)
STAND_ASIDE_BELOW = 0.8  # the share of hits below which the memory stands aside
SPEAK_AGAIN_ABOVE = 0.9  # the share of hits above which it speaks again


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
