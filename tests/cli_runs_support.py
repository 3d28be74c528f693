"""What the tests of ``dcqn-campusnav``'s runs share: cheap views, a small entry with a start curriculum, a road,
Ctrl-C inside training."""

from __future__ import annotations

from stable_baselines3.common.callbacks import BaseCallback

from sb3_dcqn.campusnav.cli import build_parser, run

FAST = ("--encoder", "pixels", "--render-size", "64", "48", "--no-progress")
# A small entry with a start curriculum (the city entries' callback)
TINY_CONF = """\
CampusNav-v0:
  n_timesteps: 300
  policy: 'MultiInputPolicy'
  env_kwargs:
    view_dim: 16
    max_steps: 40
  learning_rate: !!float 1e-3
  buffer_size: 2000
  learning_starts: 100
  batch_size: 32
  target_update_interval: 100
  callback:
    - campusnav_env.callbacks.StartCurriculumCallback:
        initial: 2
        window: 5
  policy_kwargs: "dict(features_extractor_class=EmbeddingFusionExtractor, features_extractor_kwargs=dict(embed_dim=16, \
features_dim=16), share_features_extractor=True, net_arch=[16], heading_key='heading')"
"""
ROAD = (14, 15)  # a road of the built-in campus whose closure keeps every goal reachable


def cli(*argv: str) -> dict:
    """The command line in process: its summary (bad input raises ``CommandError``)."""
    return run(build_parser().parse_args(list(argv)))


class CtrlC(BaseCallback):
    """Raises ``KeyboardInterrupt`` inside ``learn()`` at an env step, where Ctrl-C's SIGINT would."""

    def __init__(self, at: int) -> None:
        super().__init__()
        self.at = at

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.at:
            raise KeyboardInterrupt
        return True
