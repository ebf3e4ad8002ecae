"""The algorithm registry: names of the paper's learners -> SB3 / sb3-contrib classes.

With :class:`~wrappers.ParameterSharingVecEnv` every AV is a slot of one VecEnv, so each SB3
algorithm trains one policy shared by all AVs: A2C acts as MA2C, PPO as MAPPO, and so on; our
own :class:`~sb3_marl.algos.acktr.ACKTR` (K-FAC) acts as MAACKTR. MA2C, MAPPO, MAACKTR and MADQN mask
unavailable meta-actions (:mod:`sb3_marl.algos.common.base`), as the authors' MA2C does.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

#: Learner name -> "module:class" (imported on first use: torch is not loaded by the CLI's --help).
ALGO_CLASSES: dict[str, str] = {
    "ma2c": "sb3_marl.algos.a2c:MaskableA2C",
    "mappo": "sb3_marl.algos.ppo:MaskedPPO",
    "madqn": "sb3_marl.algos.dqn:MaskableDQN",
    "matrpo": "sb3_marl.algos.trpo:SafeTRPO",
    "maacktr": "sb3_marl.algos.acktr:MaskableACKTR",
}
ALGO_NAMES: tuple[str, ...] = tuple(sorted(ALGO_CLASSES))
#: Other names :func:`get_algo` takes (the algorithm's own name for a learner the paper names MA...);
#: the command line takes only :data:`ALGO_NAMES`, each learner under one name.
ALIASES: dict[str, str] = {"acktr": "maacktr"}


def get_algo(name: str) -> type[BaseAlgorithm]:
    """The class registered under ``name`` (or an alias); a ValueError listing the valid names otherwise."""
    name = ALIASES.get(name, name)
    if name not in ALGO_CLASSES:
        raise ValueError(f"Unknown algorithm {name!r}: expected one of {list(ALGO_NAMES)}.")
    module, cls = ALGO_CLASSES[name].split(":")
    return getattr(import_module(module), cls)


def __getattr__(name: str) -> Any:
    """``ALGOS``: name -> class, every class imported."""
    if name == "ALGOS":
        return {algo: get_algo(algo) for algo in ALGO_NAMES}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
