"""What a slot's info holds (see :class:`~wrappers.ParameterSharingVecEnv`): each AV's share of
its copy's step info, as per-slot arrays (:func:`copy_arrays`, :func:`join_arrays`) that a
:class:`SlotInfo` reads its row of when asked, and how a copy's episode ended (:class:`Ending`)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any, NamedTuple

import numpy as np

from sb3_marl.envs.reward import REWARD_MODES, mode_rewards

#: Per-AV arrays of the scenario's info that each slot's info carries as scalars.
PER_AGENT_INFO = (
    "speed",
    "headway",
    "acceleration",
    "lane_change",
    "crashed",
    "exited",
    "action_mask",
    "proposed_action",
    "executed_action",
    "intervened",
    "rule_action",
)


#: Slot-info entries read as Python numbers (the others are the arrays' numpy values).
FLOAT_ENTRIES, INT_ENTRIES = ("reward", "global_reward"), ("copy", "agent")


def copy_arrays(info: dict[str, Any]) -> dict[str, Any]:
    """What the slot infos of a copy's AVs carry, as per-AV arrays (n_avs, ...): the entries of
    :data:`PER_AGENT_INFO`, ``reward`` (the AV's own), ``global_reward`` (the copy's mean) and
    ``reward_terms`` (a dict of arrays)."""
    own = np.asarray(info["rewards"], dtype=np.float64)
    arrays: dict[str, Any] = {key: np.asarray(info[key]) for key in PER_AGENT_INFO if key in info}
    arrays["reward"] = own
    arrays["global_reward"] = mode_rewards(own, np.ones((own.size, own.size), dtype=np.bool_), REWARD_MODES.index("global"))
    arrays["reward_terms"] = {name: np.asarray(values) for name, values in info.get("reward_terms", {}).items()}
    return arrays


def join_arrays(parts: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The per-slot arrays of several copies' :func:`copy_arrays`, copy after copy (the entries all share)."""
    keys = [key for key in parts[0] if key != "reward_terms" and all(key in part for part in parts)]
    joined: dict[str, Any] = {key: np.concatenate([part[key] for part in parts]) for key in keys}
    terms = [part["reward_terms"] for part in parts]
    shared = [name for name in terms[0] if all(name in t for t in terms)]
    joined["reward_terms"] = {name: np.concatenate([t[name] for t in terms]) for name in shared}
    return joined


def slice_arrays(arrays: dict[str, Any], slots: slice) -> dict[str, Any]:
    """The per-slot arrays of the ``slots`` only (one copy's share of :func:`join_arrays`' result)."""
    part = {key: values[slots] for key, values in arrays.items() if key != "reward_terms"}
    part["reward_terms"] = {name: values[slots] for name, values in arrays["reward_terms"].items()}
    return part


class SlotInfo(dict):
    """One slot's info (see :class:`~wrappers.ParameterSharingVecEnv`), a dict: its row of the
    step's per-slot arrays, read when asked, and entries of its own (``terminal_observation``,
    ``episode``, what wrappers add), stored as a dict's. Building one costs no more than an empty
    dict; a consumer that wants every slot's value reads :attr:`arrays` whole."""

    __slots__ = ("arrays", "deleted", "slot")

    def __init__(self, arrays: dict[str, Any], slot: int) -> None:
        super().__init__()
        self.arrays, self.slot = arrays, slot
        self.deleted: tuple[str, ...] = ()

    def _row(self, key: str) -> Any:
        if key == "reward_terms":
            return {name: float(values[self.slot]) for name, values in self.arrays[key].items()}
        value = self.arrays[key][self.slot]
        return float(value) if key in FLOAT_ENTRIES else int(value) if key in INT_ENTRIES else value

    def _shared(self, key: object) -> bool:
        return key in self.arrays and not dict.__contains__(self, key) and key not in self.deleted

    def __getitem__(self, key: str) -> Any:
        if dict.__contains__(self, key):
            return dict.__getitem__(self, key)
        if key in self.deleted:
            raise KeyError(key)
        return self._row(key)

    def get(self, key: str, default: Any = None) -> Any:
        if key not in self:
            return default
        return self[key]

    def __contains__(self, key: object) -> bool:
        return dict.__contains__(self, key) or self._shared(key)

    def __delitem__(self, key: str) -> None:
        if dict.__contains__(self, key):
            dict.__delitem__(self, key)
        elif self._shared(key):
            self.deleted = (*self.deleted, key)
        else:
            raise KeyError(key)

    def __iter__(self) -> Iterator[str]:
        yield from (key for key in self.arrays if self._shared(key))
        yield from dict.__iter__(self)

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def keys(self) -> list[str]:  # type: ignore[override]
        return list(self)

    def items(self) -> list[tuple[str, Any]]:  # type: ignore[override]
        return [(key, self[key]) for key in self]

    def values(self) -> list[Any]:  # type: ignore[override]
        return [self[key] for key in self]

    def copy(self) -> dict[str, Any]:
        """A plain dict of every entry (SB3's ``VecMonitor`` copies infos)."""
        return dict(self.items())

    def __eq__(self, other: object) -> bool:
        return isinstance(other, dict) and dict(self.items()) == dict(other.items())

    __hash__ = None

    def __repr__(self) -> str:
        return f"SlotInfo({dict(self.items())!r})"


def slot_infos(arrays: dict[str, Any]) -> list[SlotInfo]:
    """One :class:`SlotInfo` per slot of the per-slot ``arrays``."""
    return [SlotInfo(arrays, slot) for slot in range(len(arrays["reward"]))]


def slot_column(infos: Sequence[dict[str, Any]], key: str, default: Any) -> Any:
    """Every slot's ``info.get(key, default)``, in slot order: the step's per-slot array itself
    (not a copy) when ``infos`` are one step's :class:`SlotInfo` rows and none holds ``key`` as an
    entry of its own (and ``key`` is none that a row converts to a Python number), else a list read
    row by row."""
    arrays: Any = getattr(infos[0], "arrays", None) if len(infos) else None
    shared = arrays is not None and key in arrays and len(arrays[key]) == len(infos) and key not in FLOAT_ENTRIES + INT_ENTRIES
    rows = enumerate(infos)
    if shared and all(type(i) is SlotInfo and i.arrays is arrays and i.slot == n and i._shared(key) for n, i in rows):
        return arrays[key]
    return [info.get(key, default) for info in infos]


class Ending(NamedTuple):
    """How a copy's episode ended: its last observations (n_avs, ...), whether by a time limit or
    the road's end (SB3's ``TimeLimit.truncated``; a crash is a termination), and the slot-info
    arrays of the new episode's first observations."""

    terminal_observation: np.ndarray
    time_limit: bool
    reset_arrays: dict[str, Any]
