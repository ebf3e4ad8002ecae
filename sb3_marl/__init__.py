"""sb3-marl: multi-agent RL for cooperative lane changing of AVs, on Stable-Baselines3."""

import os

# numba caches the compiled road kernel in the user's cache folder, not beside the installed
# modules (where `pip uninstall` would leave it behind); NUMBA_CACHE_DIR, if set, wins
os.environ.setdefault(
    "NUMBA_CACHE_DIR",
    os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "sb3-marl", "numba"),
)

from sb3_marl import envs  # noqa: F401  (registers the gymnasium ids)

__version__ = "0.1.0"
