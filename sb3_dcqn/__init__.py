"""DCQN (double-critic deep Q-learning) for Stable-Baselines3."""

from sb3_dcqn.dcqn import DCQN
from sb3_dcqn.policies import CnnPolicy, DCQNPolicy, MlpPolicy, MultiInputPolicy, TwinQNetwork
from sb3_dcqn.targets import blocked_actions, dcqn_td_target

__version__ = "0.1.0"

__all__ = [
    "DCQN",
    "CnnPolicy",
    "DCQNPolicy",
    "MlpPolicy",
    "MultiInputPolicy",
    "TwinQNetwork",
    "__version__",
    "blocked_actions",
    "dcqn_td_target",
]
