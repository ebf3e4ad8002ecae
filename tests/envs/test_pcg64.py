"""The compiled generator (:mod:`sb3_marl.sim.pcg64`) draws NumPy's numbers, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_marl.sim import pcg64


@pytest.mark.parametrize("seed", [0, 1, 7, 123456789, 2**40 + 3])
def test_draws_equal_numpy(seed: int) -> None:
    numpy_rng = np.random.default_rng(seed)
    words = pcg64.read_state(np.random.default_rng(seed))
    for population, size in [(60, 5), (60, 30), (6, 3), (6, 0), (40, 39), (6, 6), (1, 1), (150, 140)]:
        assert pcg64.integers(words, 3, 11) == numpy_rng.integers(3, 11)
        np.testing.assert_array_equal(pcg64.choice(words, population, size), numpy_rng.choice(population, size, replace=False))
        np.testing.assert_array_equal(pcg64.uniform(words, -1.0, 1.0, size), numpy_rng.uniform(-1.0, 1.0, size))
        assert pcg64.random(words) == numpy_rng.random()
    again = np.random.default_rng()
    pcg64.write_state(again, words)  # the state goes back: the same draws go on
    assert again.random() == numpy_rng.random()
    np.testing.assert_array_equal(pcg64.read_state(again), pcg64.read_state(numpy_rng))


def test_buffered_half_survives_the_round_trip() -> None:
    numpy_rng = np.random.default_rng(5)
    numpy_rng.integers(0, 7)  # one 32-bit draw: the 64-bit draw's upper half waits in the buffer
    words = pcg64.read_state(numpy_rng)
    assert words[pcg64.HAS_UINT32] == 1
    assert pcg64.integers(words, 0, 1000) == numpy_rng.integers(0, 1000)


def test_other_bit_generators_are_refused() -> None:
    with pytest.raises(ValueError, match="PCG64"):
        pcg64.read_state(np.random.Generator(np.random.MT19937(0)))
