"""MATRPO: sb3-contrib's TRPO, loaded without unpickling."""

from __future__ import annotations

from sb3_contrib import TRPO

from sb3_marl.algos.common.loading import safe_load


class SafeTRPO(TRPO):
    """sb3-contrib's ``TRPO`` (``matrpo``) whose ``load`` never unpickles
    (:data:`~sb3_marl.algos.common.loading.safe_load`)."""

    load = safe_load
