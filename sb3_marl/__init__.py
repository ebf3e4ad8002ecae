"""sb3-marl: multi-agent RL for cooperative lane changing of AVs, on Stable-Baselines3."""

from sb3_marl import envs  # noqa: F401  (registers the gymnasium ids)

__version__ = "0.1.0"
