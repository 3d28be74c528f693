"""What a replay buffer hears back from the training step: the one channel between ``train()`` and the variants.

An algorithm's ``train()`` samples a batch, computes its TD errors and takes a gradient step; some replay variants
need something of that step (prioritized replay: the batch's TD errors as its new priorities, and how far training
has come, to anneal its importance correction) or have something to report (experience revision: how many stored
transitions it rewrote). Rather than a ``train()`` that asks which buffer it has, every DCQN buffer is a
:class:`TrainingFeedback` and answers two calls, no-ops unless a variant overrides them:

- :meth:`TrainingFeedback.loss_weights`: per-sample weights of a sampled batch's loss (``None``: unweighted);
- :meth:`TrainingFeedback.after_gradient_step`: the batch, its absolute TD errors and the share of training done;
  returns the statistics to log under ``train/``.

Mix-ins extend them through ``super()``. :func:`feedback_of` gives the training step the buffer's feedback: the
buffer itself, or a no-op for SB3's buffers and a user's own classes (which take none).
"""

from __future__ import annotations

from typing import Any

import torch as th

__all__ = ["TrainingFeedback", "feedback_of"]


class TrainingFeedback:
    """The training step's feedback to a replay buffer (see the module docstring): nothing to do, nothing to report."""

    def loss_weights(self, samples: Any) -> th.Tensor | None:
        """
        Per-sample weights of the loss of a batch this buffer sampled.

        :param samples: The batch
        :return: weights, shape ``(batch, 1)``, or ``None`` for an unweighted loss
        """
        return None

    def after_gradient_step(self, samples: Any, td_errors: th.Tensor, progress: float) -> dict[str, float]:
        """
        Called after each gradient step on a batch this buffer sampled.

        :param samples: The batch
        :param td_errors: Its absolute TD errors (detached, on the model's device), shape ``(batch, 1)``
        :param progress: The share of training done, from 0 to 1
        :return: statistics to log under ``train/`` (name -> value)
        """
        return {}


_NO_FEEDBACK = TrainingFeedback()


def feedback_of(buffer: Any) -> TrainingFeedback:
    """The feedback channel of a replay buffer: the buffer itself where it is one of DCQN's, a no-op otherwise."""
    return buffer if isinstance(buffer, TrainingFeedback) else _NO_FEEDBACK
