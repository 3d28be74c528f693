"""DCQN's temporal-difference target: the minimum over the target critics, and the blocked-action variant."""

from __future__ import annotations

import torch as th
from torch.nn import functional as F


def blocked_actions(
    observations: th.Tensor | dict[str, th.Tensor],
    next_observations: th.Tensor | dict[str, th.Tensor],
    actions: th.Tensor,
    n_actions: int,
) -> th.Tensor:
    """
    The actions that left the observation unchanged, as a mask for :func:`dcqn_td_target`.

    In a deterministic world an action after which the agent observes exactly what it observed before (a collision:
    no road that way, or a closed one) will do the same again, so its value is the step's reward plus the value of
    the best *other* action: ``Q(s, a) = r + gamma * max_{a' != a} Q(s, a')``.

    :param observations: Observations of a batch (a tensor or a dict of tensors)
    :param next_observations: The next observations
    :param actions: Actions taken, shape ``(batch, 1)``
    :param n_actions: Number of discrete actions
    :return: Boolean mask ``(batch, n_actions)``: the taken action of each row whose observation did not change
    """
    if isinstance(observations, dict):
        pairs = [(observations[key], next_observations[key]) for key in observations]  # type: ignore[index]
    else:
        pairs = [(observations, next_observations)]
    unchanged = th.ones(actions.shape[0], dtype=th.bool, device=actions.device)
    for before, after in pairs:
        unchanged &= (before == after).reshape(before.shape[0], -1).all(dim=1)
    taken = F.one_hot(actions.reshape(-1).long(), n_actions).bool()
    return taken & unchanged[:, None]


def dcqn_td_target(
    next_q_values: th.Tensor,
    rewards: th.Tensor,
    dones: th.Tensor,
    discounts: th.Tensor | float,
    excluded_actions: th.Tensor | None = None,
    pessimistic: bool = True,
) -> th.Tensor:
    """
    The DCQN temporal-difference target ``y = r + gamma * (1 - done) * max_a' min_i Q'_i(s', a')``.

    Taking the element-wise minimum over the target critics before the max curbs the over-estimation of the max
    operator. With ``pessimistic=False`` (an ablation) the first target critic alone is used:
    ``y = r + gamma * (1 - done) * max_a' Q'_1(s', a')``.

    :param next_q_values: Target critics' Q-values at the next observations, shape ``(n_critics, batch, n_actions)``
    :param rewards: Shape ``(batch, 1)``
    :param dones: Episode-termination flags, shape ``(batch, 1)`` (timeouts are already handled by the buffer)
    :param discounts: ``gamma`` (or ``gamma ** n`` per row for n-step returns, shape ``(batch, 1)``)
    :param excluded_actions: Boolean mask ``(batch, n_actions)`` of actions left out of the max (at least one action
        of each row must stay in)
    :param pessimistic: Take the element-wise minimum over the target critics (DCQN); ``False``: the first target
        critic's values
    :return: The TD target, shape ``(batch, 1)``
    """
    next_q = next_q_values.min(dim=0).values if pessimistic else next_q_values[0]
    if excluded_actions is not None:
        next_q = next_q.masked_fill(excluded_actions, -th.inf)
    next_value = next_q.max(dim=1).values.reshape(-1, 1)
    return rewards + (1 - dones) * discounts * next_value
