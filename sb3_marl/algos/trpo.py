"""MATRPO: sb3-contrib's TRPO, loaded without unpickling."""

from __future__ import annotations

from sb3_contrib import TRPO

from sb3_marl.algos.common.loading import SafeLoading


class SafeTRPO(SafeLoading, TRPO):
    """sb3-contrib's ``TRPO`` (``matrpo``) whose ``load`` never unpickles
    (:class:`~sb3_marl.algos.common.loading.SafeLoading`)."""
