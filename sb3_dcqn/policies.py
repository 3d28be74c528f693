"""Twin-critic Q-network policies for DCQN.

Both critics live in one module: their MLP heads are stacked into batched ("ensemble") linear layers, so one forward
pass (one matrix multiply per layer) evaluates every critic. Features extractors without parameters (flatten, SB3's
``CombinedExtractor`` over vector spaces) are run once and shared; extractors with parameters are either shared
(``share_features_extractor=True``) or, as in the paper, one per critic.
"""

from __future__ import annotations

import math
from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.torch_layers import (
    BaseFeaturesExtractor,
    CombinedExtractor,
    FlattenExtractor,
    NatureCNN,
)
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn


class EnsembleLinear(nn.Module):
    """
    ``n_members`` independent linear layers evaluated with one batched matrix multiply.

    Input of shape ``(batch, in_features)`` is shared by all members; input of shape
    ``(n_members, batch, in_features)`` gives each member its own rows. Output: ``(n_members, batch, out_features)``.
    Each member is initialised exactly like ``nn.Linear``.

    :param n_members: Number of independent layers
    :param in_features: Input size
    :param out_features: Output size
    """

    def __init__(self, n_members: int, in_features: int, out_features: int) -> None:
        super().__init__()
        self.n_members = n_members
        self.in_features = in_features
        self.out_features = out_features
        self.weight = nn.Parameter(th.empty(n_members, in_features, out_features))
        self.bias = nn.Parameter(th.empty(n_members, 1, out_features))
        self.reset_parameters()

    def reset_parameters(self) -> None:
        # nn.Linear's default: kaiming_uniform(a=sqrt(5)) reduces to U(-1/sqrt(fan_in), 1/sqrt(fan_in)) for both
        bound = 1.0 / math.sqrt(self.in_features) if self.in_features > 0 else 0.0
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: th.Tensor) -> th.Tensor:
        if x.dim() == 2:
            # A shared input is expanded as a view (no copy); one baddbmm beats a broadcast matmul on CPU
            x = x.unsqueeze(0).expand(self.n_members, -1, -1)
        return th.baddbmm(self.bias, x, self.weight)

    def extra_repr(self) -> str:
        return f"n_members={self.n_members}, in_features={self.in_features}, out_features={self.out_features}"


def create_ensemble_mlp(
    n_members: int,
    input_dim: int,
    output_dim: int,
    net_arch: list[int],
    activation_fn: type[nn.Module] = nn.ReLU,
) -> nn.Sequential:
    """
    Stack of ``EnsembleLinear`` layers: ``n_members`` MLPs with the same architecture, evaluated together.

    :param n_members: Number of independent MLPs
    :param input_dim: Input size
    :param output_dim: Output size of the last layer
    :param net_arch: Hidden layer sizes
    :param activation_fn: Activation between layers (none after the last one)
    :return: the ensemble MLP, mapping ``(batch, input_dim)`` or ``(n, batch, input_dim)`` to ``(n, batch, output_dim)``
    """
    layers: list[nn.Module] = []
    last_dim = input_dim
    for hidden_dim in net_arch:
        layers += [EnsembleLinear(n_members, last_dim, hidden_dim), activation_fn()]
        last_dim = hidden_dim
    layers.append(EnsembleLinear(n_members, last_dim, output_dim))
    return nn.Sequential(*layers)


def _check_heading_key(observation_space: spaces.Space, action_space: spaces.Space, heading_key: str | None) -> None:
    """A heading key must name a one-hot Box with one entry per action in a Dict observation."""
    if heading_key is None:
        return
    if not isinstance(observation_space, spaces.Dict) or heading_key not in observation_space.spaces:
        raise ValueError(f"heading_key {heading_key!r} is not a key of the Dict observation space {observation_space}")
    n_actions = int(action_space.n) if isinstance(action_space, spaces.Discrete) else -1
    if observation_space[heading_key].shape != (n_actions,):
        raise ValueError(
            f"heading_key {heading_key!r}: the heading must be one-hot over the {n_actions} relative actions, got "
            f"shape {observation_space[heading_key].shape}"
        )


def fused_adam_default(optimizer_class: type[th.optim.Optimizer], parameters: list[nn.Parameter]) -> dict[str, Any]:
    """
    ``{"fused": True}`` for Adam where this torch supports the fused kernel for these parameters, else ``{}``.

    Fused Adam updates every parameter in one pass instead of one Python-level loop of element-wise ops per tensor:
    the same algorithm, one third to one half of the optimizer's time on small networks.

    :param optimizer_class: The policy's optimizer class
    :param parameters: The parameters it will update
    :return: The keyword arguments to add to the optimizer's
    """
    if optimizer_class is not th.optim.Adam or not parameters:
        return {}
    try:  # Older torch builds have no fused kernel for some devices (CPU before torch 2.4)
        th.optim.Adam([th.zeros(1, device=parameters[0].device, requires_grad=True)], fused=True)
    except (RuntimeError, TypeError, ValueError):
        return {}
    return {"fused": True}


def _has_parameters(module: nn.Module) -> bool:
    return any(True for _ in module.parameters())


class TwinQNetwork(BasePolicy):
    """
    Several Q-value critics evaluated in one pass (DCQN uses two).

    :param observation_space: Observation space
    :param action_space: Action space
    :param features_extractors: One features extractor shared by all critics, or one per critic
    :param features_dim: Number of features each extractor outputs
    :param net_arch: Hidden layer sizes of each critic's MLP
    :param activation_fn: Activation function
    :param normalize_images: Whether to normalize images or not, dividing by 255.0 (True by default)
    :param n_critics: Number of critics
    :param heading_key: Observation key of a one-hot heading to which the actions are relative (see
        :class:`DCQNPolicy`); ``None``: the critics score the actions directly
    """

    action_space: spaces.Discrete

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Discrete,
        features_extractors: list[BaseFeaturesExtractor],
        features_dim: int,
        net_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        normalize_images: bool = True,
        n_critics: int = 2,
        heading_key: str | None = None,
    ) -> None:
        if len(features_extractors) not in (1, n_critics):
            raise ValueError(
                f"TwinQNetwork needs 1 shared features extractor or one per critic ({n_critics}), "
                f"got {len(features_extractors)}"
            )
        super().__init__(
            observation_space,
            action_space,
            features_extractor=features_extractors[0],
            normalize_images=normalize_images,
        )
        if net_arch is None:
            net_arch = [64, 64]
        self.net_arch = net_arch
        self.activation_fn = activation_fn
        self.features_dim = features_dim
        self.n_critics = n_critics
        self.heading_key = heading_key
        # The first extractor is registered by BasePolicy as `features_extractor`; the others (if any) live here
        self.extra_features_extractors = nn.ModuleList(features_extractors[1:])
        self.q_net = create_ensemble_mlp(n_critics, features_dim, int(action_space.n), net_arch, activation_fn)

    @property
    def shares_features_extractor(self) -> bool:
        return len(self.extra_features_extractors) == 0

    def forward(self, obs: PyTorchObs) -> th.Tensor:
        """
        Predict the q-values that the greedy action maximises: the mean of the critics' values (as DQN's
        ``q_net(obs)``, shape ``(batch, n_actions)``).

        :param obs: Observation
        :return: The mean of the critics' Q-values, shape ``(batch, n_actions)``
        """
        return self.critic_values(obs).mean(dim=0)

    def critic_values(self, obs: PyTorchObs) -> th.Tensor:
        """
        Predict the q-values of every critic, in one batched pass.

        :param obs: Observation
        :return: Q-values of shape ``(n_critics, batch, n_actions)``
        """
        seen = obs
        if self.heading_key is not None:
            assert isinstance(obs, dict)
            seen = {key: value for key, value in obs.items() if key != self.heading_key}
        if self.shares_features_extractor:
            features = self.extract_features(seen, self.features_extractor)
        else:
            extractors = [self.features_extractor, *self.extra_features_extractors]
            features = th.stack([self.extract_features(seen, extractor) for extractor in extractors])
        q_values = self.q_net(features)
        if self.heading_key is None:
            return q_values
        # The critics scored the absolute directions; action a at heading h takes direction (h + a) % n
        n_directions = q_values.shape[-1]
        heading = obs[self.heading_key].argmax(dim=1)  # type: ignore[index]
        directions = (heading[:, None] + th.arange(n_directions, device=heading.device)[None, :]) % n_directions
        return th.gather(q_values, 2, directions.unsqueeze(0).expand(q_values.shape[0], -1, -1))

    def _predict(self, observation: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        # Greedy action on the mean of the critics: the same rule in predict, evaluation and exploration
        return self(observation).argmax(dim=1).reshape(-1)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            dict(
                net_arch=self.net_arch,
                features_dim=self.features_dim,
                activation_fn=self.activation_fn,
                features_extractors=[self.features_extractor, *self.extra_features_extractors],
                n_critics=self.n_critics,
                heading_key=self.heading_key,
            )
        )
        return data


class DCQNPolicy(BasePolicy):
    """
    Policy class with twin critics and twin target critics for DCQN.

    The greedy action maximises the mean of the critics' Q-values; the TD target (in ``DCQN.train``) uses the
    element-wise minimum of the target critics.

    :param observation_space: Observation space
    :param action_space: Action space
    :param lr_schedule: Learning rate schedule (could be constant)
    :param net_arch: The hidden layer sizes of each critic
    :param activation_fn: Activation function
    :param features_extractor_class: Features extractor to use.
    :param features_extractor_kwargs: Keyword arguments
        to pass to the features extractor.
    :param normalize_images: Whether to normalize images or not,
         dividing by 255.0 (True by default)
    :param optimizer_class: The optimizer to use,
        ``th.optim.Adam`` by default
    :param optimizer_kwargs: Additional keyword arguments,
        excluding the learning rate, to pass to the optimizer (Adam is fused where torch supports it for the
        device, see :func:`fused_adam_default`, unless ``fused`` or ``foreach`` is given here)
    :param n_critics: Number of critics (2 for DCQN)
    :param share_features_extractor: Whether the critics share one features extractor. Extractors without
        parameters are always shared, since separate copies would compute the same features.
    :param heading_key: For actions relative to a heading given in the observation as a one-hot vector under this
        key (CampusNav: ``"heading"``, actions forward/right/back/left). The critics then score the absolute
        directions from the other keys only and the policy rotates the scores into the heading's frame: action ``a``
        at heading ``h`` gets the score of direction ``(h + a) % n``. What the agent learns at one heading holds at
        every heading (a road found closed is closed whichever way the agent faces). ``None`` (default, the paper's
        critic): the heading is one more input
    """

    q_net: TwinQNetwork
    q_net_target: TwinQNetwork

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        net_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        features_extractor_class: type[BaseFeaturesExtractor] = FlattenExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
        normalize_images: bool = True,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        n_critics: int = 2,
        share_features_extractor: bool = False,
        heading_key: str | None = None,
    ) -> None:
        _check_heading_key(observation_space, action_space, heading_key)
        super().__init__(
            observation_space,
            action_space,
            features_extractor_class,
            features_extractor_kwargs,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
            normalize_images=normalize_images,
        )
        if n_critics < 1:
            raise ValueError(f"n_critics must be at least 1, got {n_critics}")
        if net_arch is None:
            net_arch = [] if features_extractor_class == NatureCNN else [64, 64]
        self.net_arch = net_arch
        self.activation_fn = activation_fn
        self.n_critics = n_critics
        self.share_features_extractor = share_features_extractor
        self.heading_key = heading_key
        self.net_args = {
            "observation_space": self.observation_space,
            "action_space": self.action_space,
            "net_arch": self.net_arch,
            "activation_fn": self.activation_fn,
            "normalize_images": normalize_images,
            "n_critics": n_critics,
            "heading_key": heading_key,
        }
        self._build(lr_schedule)

    def _build(self, lr_schedule: Schedule) -> None:
        """
        Create the networks and the optimizer; put the target critics into evaluation mode.

        :param lr_schedule: Learning rate schedule
            lr_schedule(1) is the initial learning rate
        """
        self.q_net = self.make_q_net()
        self.q_net_target = self.make_q_net()
        self.q_net_target.load_state_dict(self.q_net.state_dict())
        self.q_net_target.set_training_mode(False)

        parameters = list(self.q_net.parameters())
        chosen = {"fused", "foreach"} & set(self.optimizer_kwargs)
        implementation = {} if chosen else fused_adam_default(self.optimizer_class, parameters)
        self.optimizer = self.optimizer_class(  # type: ignore[call-arg]
            parameters,
            lr=lr_schedule(1),
            **implementation,
            **self.optimizer_kwargs,
        )

    def make_features_extractor(self) -> BaseFeaturesExtractor:
        """A features extractor of the observation, without the heading when the actions are relative to it."""
        if self.heading_key is None:
            return super().make_features_extractor()
        assert isinstance(self.observation_space, spaces.Dict)
        seen = spaces.Dict({k: v for k, v in self.observation_space.spaces.items() if k != self.heading_key})
        return self.features_extractor_class(seen, **self.features_extractor_kwargs)

    def make_q_net(self) -> TwinQNetwork:
        # Always fresh extractors, so that online and target critics share no parameters
        first = self.make_features_extractor()
        if self.share_features_extractor or not _has_parameters(first):
            extractors = [first]
        else:
            extractors = [first] + [self.make_features_extractor() for _ in range(self.n_critics - 1)]
        return TwinQNetwork(features_extractors=extractors, features_dim=first.features_dim, **self.net_args).to(
            self.device
        )

    def forward(self, obs: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        return self._predict(obs, deterministic=deterministic)

    def _predict(self, obs: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        return self.q_net._predict(obs, deterministic=deterministic)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            dict(
                net_arch=self.net_args["net_arch"],
                activation_fn=self.net_args["activation_fn"],
                lr_schedule=self._dummy_schedule,  # dummy lr schedule, not needed for loading policy alone
                optimizer_class=self.optimizer_class,
                optimizer_kwargs=self.optimizer_kwargs,
                features_extractor_class=self.features_extractor_class,
                features_extractor_kwargs=self.features_extractor_kwargs,
                n_critics=self.n_critics,
                share_features_extractor=self.share_features_extractor,
                heading_key=self.heading_key,
            )
        )
        return data

    def set_training_mode(self, mode: bool) -> None:
        """
        Put the policy in either training or evaluation mode.

        This affects certain modules, such as batch normalisation and dropout.

        :param mode: if true, set to training mode, else set to evaluation mode
        """
        self.q_net.set_training_mode(mode)
        self.training = mode


MlpPolicy = DCQNPolicy


class CnnPolicy(DCQNPolicy):
    """
    Policy class for DCQN when using images as input: :class:`DCQNPolicy` with ``NatureCNN`` as the default
    features extractor. Takes the same keyword arguments.
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        features_extractor_class: type[BaseFeaturesExtractor] = NatureCNN,
        **kwargs: Any,
    ) -> None:
        super().__init__(
            observation_space, action_space, lr_schedule, features_extractor_class=features_extractor_class, **kwargs
        )


class MultiInputPolicy(DCQNPolicy):
    """
    Policy class for DCQN when using dict observations as input: :class:`DCQNPolicy` with SB3's
    ``CombinedExtractor`` as the default features extractor. Takes the same keyword arguments.
    """

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        features_extractor_class: type[BaseFeaturesExtractor] = CombinedExtractor,
        **kwargs: Any,
    ) -> None:
        super().__init__(
            observation_space, action_space, lr_schedule, features_extractor_class=features_extractor_class, **kwargs
        )
