"""DCQN (double-critic deep Q-learning) for Stable-Baselines3."""

from sb3_dcqn.dcqn import DCQN, dcqn_td_target
from sb3_dcqn.policies import CnnPolicy, DCQNPolicy, MlpPolicy, MultiInputPolicy, TwinQNetwork

__version__ = "0.1.0"

__all__ = [
    "DCQN",
    "CnnPolicy",
    "DCQNPolicy",
    "MlpPolicy",
    "MultiInputPolicy",
    "TwinQNetwork",
    "__version__",
    "dcqn_td_target",
]
