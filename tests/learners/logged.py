"""What a learner logs, kept in memory through SB3's own logger interface."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.logger import KVWriter


class Dumps(KVWriter):
    """Keeps every logger dump (SB3's logger output interface)."""

    def __init__(self) -> None:
        self.dumps: list[dict[str, Any]] = []

    def write(self, key_values: dict[str, Any], key_excluded: dict[str, Any], step: int = 0) -> None:
        self.dumps.append(dict(key_values))

    def values(self, key: str) -> list:
        return [dump[key] for dump in self.dumps if key in dump]
