"""NumPy's default generator (``np.random.Generator(PCG64)``) inside compiled code, on a state array.

Compiled code (a copy's spawn inside :func:`~sb3_marl.envs.batch_kernel.step_copies`) draws from a
generator state held in a (6,) uint64 array: PCG64's 128-bit state and increment (high and low
words), then ``has_uint32`` and ``uinteger`` (the buffered half of a 64-bit draw). The draws are
NumPy's, bit for bit (``integers``, ``uniform``, ``random``, ``choice(..., replace=False)``:
tests/sim/test_pcg64.py), so an episode spawned here is the one the env's own ``np_random``
would have spawned; :func:`read_state` and :func:`write_state` move the state between the two.
"""

from __future__ import annotations

import numpy as np

from sb3_marl.sim.kernel import jit

#: Words of a generator state array.
STATE_HI, STATE_LO, INC_HI, INC_LO, HAS_UINT32, UINTEGER = range(6)
_MULT_HI, _MULT_LO = np.uint64(0x2360ED051FC65DA4), np.uint64(0x4385DF649FCCF645)  # PCG's 128-bit multiplier
_WORD = (1 << 64) - 1


def read_state(generator: np.random.Generator) -> np.ndarray:
    """(6,) uint64: a PCG64 generator's state (a ValueError for another bit generator)."""
    state = generator.bit_generator.state
    if state["bit_generator"] != "PCG64":
        raise ValueError(f"Invalid generator: expected NumPy's PCG64 (gymnasium's np_random), got {state['bit_generator']}.")
    s, inc = state["state"]["state"], state["state"]["inc"]
    words = (s >> 64, s & _WORD, inc >> 64, inc & _WORD, state["has_uint32"], state["uinteger"])
    return np.array(words, dtype=np.uint64)


def write_state(generator: np.random.Generator, words: np.ndarray) -> None:
    """Set a PCG64 generator to the state array ``words`` (:func:`read_state`'s layout)."""
    w = [int(word) for word in words]
    generator.bit_generator.state = {
        "bit_generator": "PCG64",
        "state": {"state": (w[STATE_HI] << 64) | w[STATE_LO], "inc": (w[INC_HI] << 64) | w[INC_LO]},
        "has_uint32": w[HAS_UINT32],
        "uinteger": w[UINTEGER],
    }


@jit
def _mul64(a: np.uint64, b: np.uint64) -> tuple[np.uint64, np.uint64]:
    """The 128-bit product of two 64-bit words: (high, low)."""
    mask = np.uint64(0xFFFFFFFF)
    a_lo, a_hi, b_lo, b_hi = a & mask, a >> np.uint64(32), b & mask, b >> np.uint64(32)
    lo_lo, hi_lo, lo_hi, hi_hi = a_lo * b_lo, a_hi * b_lo, a_lo * b_hi, a_hi * b_hi
    cross = (lo_lo >> np.uint64(32)) + (hi_lo & mask) + lo_hi
    high = hi_hi + (hi_lo >> np.uint64(32)) + (cross >> np.uint64(32))
    return high, (cross << np.uint64(32)) | (lo_lo & mask)


@jit
def next_uint64(g: np.ndarray) -> np.uint64:
    """PCG64's next 64-bit output (XSL-RR of the stepped state)."""
    high, low = _mul64(g[STATE_LO], _MULT_LO)
    high += g[STATE_HI] * _MULT_LO + g[STATE_LO] * _MULT_HI
    low, carry = low + g[INC_LO], np.uint64(0)
    if low < g[INC_LO]:
        carry = np.uint64(1)
    g[STATE_HI], g[STATE_LO] = high + g[INC_HI] + carry, low
    rotation = g[STATE_HI] >> np.uint64(58)
    word = g[STATE_HI] ^ g[STATE_LO]
    return (word >> rotation) | (word << ((np.uint64(64) - rotation) & np.uint64(63)))


@jit
def next_uint32(g: np.ndarray) -> np.uint64:
    """A 32-bit output: the buffered upper half of the last 64-bit draw, or a new draw's lower half."""
    if g[HAS_UINT32]:
        g[HAS_UINT32] = 0
        return g[UINTEGER]
    word = next_uint64(g)
    g[HAS_UINT32], g[UINTEGER] = 1, word >> np.uint64(32)
    return word & np.uint64(0xFFFFFFFF)


@jit
def random(g: np.ndarray) -> float:
    """``Generator.random()``: uniform in [0, 1)."""
    return float(next_uint64(g) >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@jit
def uniform(g: np.ndarray, low: float, high: float, size: int) -> np.ndarray:
    """``Generator.uniform(low, high, size)``."""
    out = np.empty(size)
    for i in range(size):
        out[i] = low + (high - low) * random(g)
    return out


@jit
def bounded(g: np.ndarray, span: int) -> np.int64:
    """Uniform in [0, ``span``] (span < 2³² - 1): NumPy's Lemire rejection on 32-bit draws."""
    if span == 0:
        return np.int64(0)
    excl = np.uint64(span + 1)
    m = next_uint32(g) * excl
    leftover = m & np.uint64(0xFFFFFFFF)
    if leftover < excl:
        threshold = (np.uint64(0xFFFFFFFF) - np.uint64(span)) % excl
        while leftover < threshold:
            m = next_uint32(g) * excl
            leftover = m & np.uint64(0xFFFFFFFF)
    return np.int64(m >> np.uint64(32))


@jit
def integers(g: np.ndarray, low: int, high: int) -> int:
    """``Generator.integers(low, high)``: one int in [low, high)."""
    return low + int(bounded(g, high - 1 - low))


@jit
def choice(g: np.ndarray, population: int, size: int) -> np.ndarray:
    """``Generator.choice(population, size, replace=False)`` for populations up to 10,000: NumPy's
    Floyd sampling into a hash set, then its shuffle of the sample."""
    out = np.empty(size, dtype=np.int64)
    if size == 0:
        return out
    mask = np.int64(1.2 * size)
    for shift in (1, 2, 4, 8, 16, 32):
        mask |= mask >> shift
    taken = np.full(mask + 1, -1, dtype=np.int64)
    for j in range(population - size, population):
        value = bounded(g, j)
        loc = value & mask
        while taken[loc] != -1 and taken[loc] != value:
            loc = (loc + 1) & mask
        if taken[loc] == -1:
            taken[loc] = out[j - population + size] = value
        else:  # drawn before: take j, which no earlier round could draw
            loc = j & mask
            while taken[loc] != -1:
                loc = (loc + 1) & mask
            taken[loc] = out[j - population + size] = j
    for i in range(size - 1, 0, -1):
        other = bounded(g, i)
        out[i], out[other] = out[other], out[i]
    return out
