"""The state of one or more roads of a scenario in one place (:class:`Roads`).

Every road's vehicles lie in one array (the kernel's layout, :mod:`~sb3_marl.sim.kernel`, AVs
first), road k's rows at ``offsets[k]:offsets[k + 1]``, and each road's episode so far (policy
steps, HDV count, the supervisor's switches, the generator words its episodes are drawn from) in
one :class:`~sb3_marl.envs.batch_kernel.CopyState`. A scenario env reads and writes its road here
(its :attr:`state`, ``steps``, ``n_hdvs`` and ``np_random`` are views of it), alone as a road of
its own or as road k of a :class:`~sb3_marl.envs.batch.RoadBatch`, which steps every road of the
store in one compiled call: there is no other copy of the state to keep in step.

The generators: a road's episodes are drawn from its words (:mod:`~sb3_marl.sim.pcg64`, NumPy's
PCG64 bit for bit), which are the env's ``np_random``. A NumPy generator handed out by the env's
``np_random`` (:meth:`Roads.lend`) mirrors them: each step reads its state back before drawing and
writes the words into it after, so draws made through either side are the same stream.
"""

from __future__ import annotations

import numpy as np

from sb3_marl.envs.batch_kernel import CopyState
from sb3_marl.envs.merge_rules import ON_RAMP_SIDE
from sb3_marl.sim import kernel, pcg64


class Roads:
    """The roads of one scenario config, road k with ``n_avs[k]`` AVs (its state empty until set).

    :param n_avs: each road's AV count
    """

    def __init__(self, n_avs: np.ndarray) -> None:
        n = len(n_avs)
        self.n_avs = np.asarray(n_avs, dtype=np.int64)
        self.slot_starts = np.concatenate([[0], np.cumsum(self.n_avs)]).astype(np.int64)
        self.states = np.zeros((0, kernel.COLUMNS))
        self.offsets = np.zeros(n + 1, dtype=np.int64)
        words = np.zeros((n, 6), dtype=np.uint64)
        zeros = np.zeros(n, dtype=np.int64)
        self.copies = CopyState(zeros, zeros > 0, zeros > 0, zeros.copy(), words, words.copy(), np.zeros(n))
        slots = int(self.slot_starts[-1])
        self.ramp_av = np.zeros(slots, dtype=np.bool_)  # the merge's: the AV started on the ramp
        self.merge_time = np.full(slots, np.nan)  # [s] the merge's: when a ramp AV reached the main road
        self._lent: dict[int, np.random.Generator] = {}  # road -> the generator mirroring its words
        self.batched = False  # whether a RoadBatch steps these roads (their envs then do not step alone)
        self.changes = 0  # counts the changes of the vehicles (a reader's cache of them is current while it holds)

    @classmethod
    def join(cls, parts: list[tuple[Roads, int]]) -> Roads:
        """One store of road ``k`` of each ``(store, k)`` in order (their generators lent out still lent)."""
        roads = cls(np.array([store.n_avs[k] for store, k in parts]))
        roads.states = np.concatenate([store.rows(k) for store, k in parts])
        roads.offsets[1:] = np.cumsum([store.offsets[k + 1] - store.offsets[k] for store, k in parts])
        for j, (store, k) in enumerate(parts):
            for field, value in zip(roads.copies, store.copies):
                field[j] = value[k]
            roads.ramp_av[roads.slots(j)] = store.ramp_av[store.slots(k)]
            roads.merge_time[roads.slots(j)] = store.merge_time[store.slots(k)]
            if k in store._lent:
                roads._lent[j] = store._lent[k]
        return roads

    def rows(self, k: int) -> np.ndarray:
        """Road k's vehicles (a view)."""
        return self.states[self.offsets[k] : self.offsets[k + 1]]

    def slots(self, k: int) -> slice:
        """Road k's AVs among all roads' AVs."""
        return slice(int(self.slot_starts[k]), int(self.slot_starts[k + 1]))

    def resized(self, n_avs: int) -> Roads:
        """A one-road store of ``n_avs`` AVs with this one-road store's episode record and
        generators (its lent generator's draws taken first), no vehicles."""
        self.read_lent()
        roads = Roads(np.array([n_avs]))
        for field, value in zip(roads.copies, self.copies):
            field[:] = value
        roads._lent = dict(self._lent)
        return roads

    def set_rows(self, k: int, state: np.ndarray) -> None:
        """Road k's vehicles become ``state`` (its AVs first)."""
        self.changes += 1
        if len(self.n_avs) == 1:  # (no copy)
            self.states = state
            self.offsets[1] = len(state)
            return
        a, b = self.offsets[k], self.offsets[k + 1]
        if b - a == len(state):
            self.states[a:b] = state
            return
        self.states = np.concatenate([self.states[:a], state, self.states[b:]])
        self.offsets[k + 1 :] += len(state) - (b - a)

    def set_all(self, states: np.ndarray, offsets: np.ndarray) -> None:
        """Every road's vehicles become ``states``, road k's at ``offsets[k]:offsets[k + 1]`` (a batch's step)."""
        self.changes += 1
        self.states, self.offsets[:] = states, offsets

    def record_merges(self, slots: slice, lane: np.ndarray, steps: np.ndarray, policy_frequency: float) -> None:
        """The merge's record after a step of the AV ``slots``: a ramp AV on the main road for the
        first time (its ``lane`` off the ramp's side) merged at its road's ``steps`` (one per AV) /
        ``policy_frequency`` s."""
        merge_time = self.merge_time[slots]
        merged = self.ramp_av[slots] & np.isnan(merge_time) & ~ON_RAMP_SIDE[lane]
        merge_time[merged] = steps[merged] / policy_frequency

    def new_situation(self, slots: slice, lane: np.ndarray) -> None:
        """The merge's record of a new situation (a reset, a new episode, ``place``) of the AV
        ``slots`` in ``lane``: those on the ramp's side are its ramp AVs, none merged yet."""
        self.ramp_av[slots], self.merge_time[slots] = ON_RAMP_SIDE[lane], np.nan

    def lend(self, k: int, generator: np.random.Generator) -> np.random.Generator:
        """``generator`` with road k's words, mirroring them from now on (see the module doc); lent
        already, it is current and its draws since become the words."""
        if self._lent.get(k) is generator:
            self.copies.generators[k] = pcg64.read_state(generator)
        else:
            pcg64.write_state(generator, self.copies.generators[k])
            self._lent[k] = generator
        return generator

    def take(self, k: int, generator: np.random.Generator) -> None:
        """Road k's words become ``generator``'s state (a seeded reset's new generator), lent to none."""
        self.copies.generators[k] = pcg64.read_state(generator)
        self._lent.pop(k, None)

    def read_lent(self) -> None:
        """Before a draw: the lent generators' states into their roads' words."""
        for k, generator in self._lent.items():
            self.copies.generators[k] = pcg64.read_state(generator)

    def write_lent(self) -> None:
        """After a draw: the roads' words into their lent generators."""
        for k, generator in self._lent.items():
            pcg64.write_state(generator, self.copies.generators[k])
