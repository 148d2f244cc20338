"""Counter-based random numbers: Philox4x32-10 keyed by (seed, pixel, sample, stream).

Convention (shared with ``kernels/rng.h``; tests depend on it):

* The generator is Philox4x32 with 10 rounds (Salmon et al. 2011, "Parallel random
  numbers: as easy as 1, 2, 3"). It maps a 128-bit counter and a 64-bit key to 128 random
  bits with a handful of 32x32->64 multiplications, so it is cheap on CPUs and GPUs alike
  and needs no state in memory beyond the counter.
* key = (seed & 0xffffffff, seed >> 32); counter = (n >> 2, pixel, sample, stream), where
  ``n`` is the index of the draw within the stream. Draw ``n`` is word ``n & 3`` of the
  block for counter ``n >> 2``, so four consecutive draws cost one Philox call.
* A uniform is the top 24 bits of a word times 2^-24: it lies in [0, 1 - 2^-24], is exactly
  representable in float32 and float64 (both backends see bit-identical values) and is
  never 1.0, so ``-log(1 - u)`` is always finite (at most 16.64).
* ``pixel`` = y * width + x with y = 0 the top row; ``sample`` is the global sample index
  (independent of how a render is split into batches); ``stream`` separates independent
  decision sequences of one path (see the STREAM_* constants), so that changing how many
  numbers one technique consumes does not shift the numbers another one sees.

The Philox constants, UNIFORM_SCALE and the STREAM_* ids are defined in volmc/constants.py.

The state of one stream lives in a small uint32 array (RNG_STATE_SIZE words):
``[key0, key1, pixel, sample, stream, n, w0, w1, w2, w3, preset, word]`` where w* caches the
current block. ``rng_preset`` makes the next draw return a given 24-bit uniform instead of
the stream's (without advancing n): that is how a low-discrepancy sampler hands the first
uniform of a free flight to the one tracking loop, which draws everything else itself.
"""

import numpy as np
from numba import njit

from ..constants import (PHILOX_M0, PHILOX_M1, PHILOX_ROUNDS, PHILOX_W0, PHILOX_W1,  # noqa: F401
                         STREAM_PATH, STREAM_SHADOW, STREAM_TEST, UNIFORM_SCALE)

_M0 = np.uint64(PHILOX_M0)
_M1 = np.uint64(PHILOX_M1)
_W0 = np.uint64(PHILOX_W0)
_W1 = np.uint64(PHILOX_W1)
MASK32 = np.uint64(0xFFFFFFFF)
SHIFT32 = np.uint64(32)

#: Words of a stream's state array (layout in the module docstring).
RNG_STATE_SIZE = 12


@njit(cache=True, inline="always")
def philox4x32_10(c0, c1, c2, c3, k0, k1):
    """Philox4x32-10 block function: four uint32 counter words and two key words in,
    four uint32 random words out (returned as uint64 holding 32-bit values)."""
    c0 = np.uint64(c0) & MASK32
    c1 = np.uint64(c1) & MASK32
    c2 = np.uint64(c2) & MASK32
    c3 = np.uint64(c3) & MASK32
    k0 = np.uint64(k0) & MASK32
    k1 = np.uint64(k1) & MASK32
    for r in range(PHILOX_ROUNDS):
        if r > 0:
            k0 = (k0 + _W0) & MASK32
            k1 = (k1 + _W1) & MASK32
        p0 = _M0 * c0
        p1 = _M1 * c2
        hi0 = p0 >> SHIFT32
        lo0 = p0 & MASK32
        hi1 = p1 >> SHIFT32
        lo1 = p1 & MASK32
        c0 = hi1 ^ c1 ^ k0
        c1 = lo1
        c2 = hi0 ^ c3 ^ k1
        c3 = lo0
    return c0, c1, c2, c3


@njit(cache=True)
def rng_init(rng, seed, pixel, sample, stream):
    """Start stream ``stream`` of sample ``sample`` of pixel ``pixel`` for ``seed`` (< 2^64)."""
    s = np.uint64(seed)
    rng[0] = np.uint32(s & MASK32)
    rng[1] = np.uint32(s >> SHIFT32)
    rng[2] = np.uint32(pixel)
    rng[3] = np.uint32(sample)
    rng[4] = np.uint32(stream)
    rng[5] = np.uint32(0)
    rng[10] = np.uint32(0)


@njit(cache=True, inline="always")
def rng_preset(rng, u24):
    """Make the next draw of the stream the uniform u24 * 2^-24 (u24 < 2^24)."""
    rng[10] = np.uint32(1)
    rng[11] = np.uint32((np.uint64(u24) << np.uint64(8)) & MASK32)


@njit(cache=True, inline="always")
def rng_drop_preset(rng):
    """Forget a preset draw nobody took (a flight that drew nothing)."""
    rng[10] = np.uint32(0)


@njit(cache=True)
def rng_next_u32(rng):
    """Next 32-bit word of the stream (advances the draw index by one), or the preset word."""
    if rng[10] != 0:
        rng[10] = np.uint32(0)
        return rng[11]
    n = np.uint64(rng[5])
    lane = n & np.uint64(3)
    if lane == 0:
        w0, w1, w2, w3 = philox4x32_10(n >> np.uint64(2), rng[2], rng[3], rng[4], rng[0], rng[1])
        rng[6] = np.uint32(w0)
        rng[7] = np.uint32(w1)
        rng[8] = np.uint32(w2)
        rng[9] = np.uint32(w3)
    rng[5] = np.uint32((n + np.uint64(1)) & MASK32)
    return rng[6 + lane]


@njit(cache=True)
def rng_next(rng):
    """Next uniform in [0, 1 - 2^-24] (float64 holding an exact 24-bit value)."""
    return float(np.uint64(rng_next_u32(rng)) >> np.uint64(8)) * UNIFORM_SCALE


@njit(cache=True)
def rng_empty():
    """A stream state with nothing started: every word 0, so no preset draw (the kernel's
    twin, which also holds the lanes' prefetched blocks, has none prefetched)."""
    return np.zeros(RNG_STATE_SIZE, np.uint32)


@njit(cache=True)
def rng_new(seed, pixel, sample, stream):
    """Allocate and initialise a stream state (convenience for tests and host code)."""
    rng = rng_empty()
    rng_init(rng, seed, pixel, sample, stream)
    return rng


@njit(cache=True)
def uniforms(seed, pixel, sample, stream, count):
    """The first ``count`` uniforms of one stream, as a float64 array."""
    rng = rng_new(seed, pixel, sample, stream)
    out = np.empty(count, np.float64)
    for i in range(count):
        out[i] = rng_next(rng)
    return out
