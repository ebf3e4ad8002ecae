"""The algorithm registry: names of the paper's learners -> SB3 / sb3-contrib classes.

With :class:`~wrappers.ParameterSharingVecEnv` every AV is a slot of one VecEnv, so each SB3
algorithm trains one policy shared by all AVs: A2C acts as MA2C, PPO as MAPPO, and so on; our
own :class:`~sb3_marl.algos.acktr.ACKTR` (K-FAC) acts as MAACKTR. MA2C, MAPPO, MAACKTR and MADQN mask
unavailable meta-actions (:mod:`sb3_marl.algos.masking`), as the authors' MA2C does.
"""

from __future__ import annotations

from sb3_contrib import TRPO
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_marl.algos.masking import MaskableA2C, MaskableACKTR, MaskableDQN, MaskedPPO

ALGOS: dict[str, type[BaseAlgorithm]] = {
    "ma2c": MaskableA2C,
    "mappo": MaskedPPO,
    "madqn": MaskableDQN,
    "matrpo": TRPO,
    "maacktr": MaskableACKTR,
    "acktr": MaskableACKTR,
}


def get_algo(name: str) -> type[BaseAlgorithm]:
    """The class registered under ``name``; a ValueError listing the valid names otherwise."""
    try:
        return ALGOS[name]
    except KeyError:
        raise ValueError(f"Unknown algorithm {name!r}: expected one of {sorted(ALGOS)}.") from None
