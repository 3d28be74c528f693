"""DCQN (double-critic deep Q-learning) for Stable-Baselines3.

The names below are imported on first use (PEP 562), so that ``import sb3_dcqn.campusnav.cli`` (the command line,
whose ``--help`` must be fast) does not import torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sb3_dcqn.dcqn import DCQN
    from sb3_dcqn.policies import CnnPolicy, DCQNPolicy, MlpPolicy, MultiInputPolicy, TwinQNetwork
    from sb3_dcqn.route_memory import RouteMemory, UntriedExplorer
    from sb3_dcqn.route_memory.layer import RouteMemoryDCQN, RouteMemoryDQN, algorithm_name, with_route_memory
    from sb3_dcqn.targets import blocked_actions, dcqn_td_target

__version__ = "0.1.0"

_MODULE_OF = {
    "DCQN": "sb3_dcqn.dcqn",
    "blocked_actions": "sb3_dcqn.targets",
    "dcqn_td_target": "sb3_dcqn.targets",
    "CnnPolicy": "sb3_dcqn.policies",
    "DCQNPolicy": "sb3_dcqn.policies",
    "MlpPolicy": "sb3_dcqn.policies",
    "MultiInputPolicy": "sb3_dcqn.policies",
    "TwinQNetwork": "sb3_dcqn.policies",
    "RouteMemory": "sb3_dcqn.route_memory",
    "UntriedExplorer": "sb3_dcqn.route_memory",
    "RouteMemoryDCQN": "sb3_dcqn.route_memory.layer",
    "RouteMemoryDQN": "sb3_dcqn.route_memory.layer",
    "algorithm_name": "sb3_dcqn.route_memory.layer",
    "with_route_memory": "sb3_dcqn.route_memory.layer",
}

__all__ = [
    "DCQN",
    "CnnPolicy",
    "DCQNPolicy",
    "MlpPolicy",
    "MultiInputPolicy",
    "RouteMemory",
    "RouteMemoryDCQN",
    "RouteMemoryDQN",
    "TwinQNetwork",
    "UntriedExplorer",
    "__version__",
    "algorithm_name",
    "blocked_actions",
    "dcqn_td_target",
    "with_route_memory",
]


def __getattr__(name: str) -> Any:
    if name in _MODULE_OF:
        value = getattr(importlib.import_module(_MODULE_OF[name]), name)
        globals()[name] = value  # once imported, a plain attribute
        return value
    raise AttributeError(f"module 'sb3_dcqn' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
