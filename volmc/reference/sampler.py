"""Low-discrepancy sample pairs: Owen-scrambled Sobol points and correlated multi-jitter.

Pure functions of explicit integers; twin of ``kernels/sampler.h`` (same names, same
arguments), bit for bit: every step is integer arithmetic (uint32, done here in np.uint64
masked to 32 bits like ``rng.py``; the stratified sampler's interval ends in 64 bits).

Conventions:

* **u24.** A sample coordinate is an integer k in [0, 2^24): the uniform k * 2^-24 (multiply
  by ``UNIFORM_SCALE``), the convention of ``rng.py``'s uniforms, exact in float32 and
  float64 and never 1.0. Functions returning a pair return ``(ux24, uy24)`` (the kernel: a
  ``uint2``). A 32-bit fraction (``sobol_u32``, ``owen_scramble``) is the integer x meaning
  x * 2^-32; its top 24 bits are the u24.
* **Arguments.** ``index``: the sample's index in its pixel (the global sample index, as
  ``rng.py``'s ``sample``), any uint32. ``pixel``: y * width + x. ``pair``: which pair of
  dimensions of the path (camera jitter, first bounce, ...); each pair is its own
  low-discrepancy pattern. ``n``: samples per pixel the stratified sampler stratifies over
  (>= 1; 0 acts as 1, more than ``SAMPLER_MAX_N`` as ``SAMPLER_MAX_N``). ``key0, key1``: the
  render seed's low and high 32-bit halves. ``seed*``: any 32-bit words; each is one random
  choice of scramble or permutation (``sampler_pair`` draws them from Philox).
* **Seeds.** ``sampler_pair`` takes the seeds of a (pixel, pair) from one Philox4x32-10 block
  with key (key0, key1) and counter (pair, pixel, epoch, STREAM_SAMPLER), epoch = index div n
  for the stratified sampler and 0 for Sobol: words 0, 1, 2 are the (shuffle or permutation,
  x, y) seeds. Pixels and pairs are decorrelated by Philox; stream STREAM_SAMPLER is not
  used by the path's random numbers.

Guarantees (tests/test_sampler.py tests each one):

* ``sobol_pair``: for every m <= 24 and k, the points of the indices [k 2^m, (k + 1) 2^m)
  form a (0, m, 2)-net in base 2: every elementary interval [a 2^-i, (a+1) 2^-i) x
  [b 2^-j, (b+1) 2^-j) with i + j = m holds exactly one point. In particular the first
  2^m samples of a pixel are a net for every m (Burley 2020's shuffled padding). Over
  seeds every point is uniform on the 24-bit grid (Owen scrambling).
* ``stratified_pair``: with m = ceil(sqrt(n)) columns and rows = ceil(n / m) (m * rows
  >= n cells, at most n + m - 1), the samples index mod n = 0 .. n-1 lie in n distinct
  cells of the m x rows grid, and in n distinct x intervals [f / (m rows), (f+1) / (m rows))
  and n distinct y intervals likewise. So when n = m * rows (n = 1, 2, 4, 6, 9, 12, 16, 20,
  ..., every square and every m (m - 1)) each cell, and each of the n 1-D intervals of
  width 1 / n on either axis, holds exactly one sample; otherwise m * rows - n cells stay
  empty, chosen at random, so that every sample is still uniform over seeds (an empty set
  of cells that never moved would bias the estimate). Samples of later epochs (index >= n)
  are new stratified sets, from new seeds (``sampler_pair``'s epoch). Inside its stratum a
  sample takes one of the stratum's 24-bit grid points, uniformly; strata hold
  floor or ceil(2^24 / (m rows)) of them, so the uniformity is exact to m rows 2^-24.
"""

import math

import numpy as np
from numba import njit

from ..constants import (HASH_M0, HASH_M1, OWEN_E0, OWEN_E1, OWEN_E2, OWEN_SEED_MUL,
                         PERM_M0, PERM_M1, PERM_M2, SAMPLER_MAX_N, SAMPLER_SOBOL,
                         SAMPLER_STRATIFIED, STREAM_SAMPLER)
from .rng import MASK32, philox4x32_10

_U = np.uint64
_E0, _E1, _E2, _SEED_MUL = _U(OWEN_E0), _U(OWEN_E1), _U(OWEN_E2), _U(OWEN_SEED_MUL)
_H0, _H1 = _U(HASH_M0), _U(HASH_M1)
_P0, _P1, _P2 = _U(PERM_M0), _U(PERM_M1), _U(PERM_M2)
_ONE = _U(1)
_S1, _S2, _S3, _S4, _S6, _S8 = _U(1), _U(2), _U(3), _U(4), _U(6), _U(8)
_S15, _S16, _S24, _S32 = _U(15), _U(16), _U(24), _U(32)
_MAX_N, _2P24 = _U(SAMPLER_MAX_N), _U(1 << 24)


@njit(cache=True, inline="always")
def _rotr(x, r):
    """32-bit right rotation of x (< 2^32) by r in 1..31 (the kernel uses ``rotate``)."""
    return ((x >> r) | (x << (_S32 - r))) & MASK32


@njit(cache=True, inline="always")
def reverse_bits32(x):
    """The 32 bits of x in reverse order (bit 0 becomes bit 31)."""
    x = _U(x) & MASK32
    x = ((x >> _S1) & _U(0x55555555)) | ((x & _U(0x55555555)) << _S1)
    x = ((x >> _S2) & _U(0x33333333)) | ((x & _U(0x33333333)) << _S2)
    x = ((x >> _S4) & _U(0x0F0F0F0F)) | ((x & _U(0x0F0F0F0F)) << _S4)
    x = ((x >> _S8) & _U(0x00FF00FF)) | ((x & _U(0x00FF00FF)) << _S8)
    return ((x >> _S16) | (x << _S16)) & MASK32


@njit(cache=True, inline="always")
def sobol_u32(index, dim):
    """Unscrambled Sobol point ``index`` (uint32), dimension ``dim``, as a 32-bit fraction.

    dim 0 is the van der Corput sequence (the bit-reversed index); any other dim gives
    dimension 1, whose generator matrix comes from the primitive polynomial x + 1: direction
    numbers m_1 = 1, m_k = 2 m_{k-1} xor m_{k-1}, i.e. v_1 = 2^31 and v_{k+1} = v_k xor
    (v_k >> 1) as 32-bit fractions: the Pascal matrix mod 2, whose entry (j, k) is
    C(k, j) mod 2, which by Lucas's theorem is 1 exactly when the bits of j are a subset of
    those of k. So digit j + 1 of the point is the parity of the index bits k that contain
    j, a superset sum over the 5-bit positions, which five masked shift-xors compute (one
    per bit of the position) before the digits are reversed into the fraction: no loop over
    the index bits. Points are in natural index order (scipy's ``qmc.Sobol`` enumerates them in Gray-code
    order: its point i is index i ^ (i >> 1) here)."""
    i = _U(index) & MASK32
    if dim == 0:
        return reverse_bits32(i)
    i ^= (i >> _S1) & _U(0x55555555)
    i ^= (i >> _S2) & _U(0x33333333)
    i ^= (i >> _S4) & _U(0x0F0F0F0F)
    i ^= (i >> _S8) & _U(0x00FF00FF)
    i ^= (i >> _S16) & _U(0x0000FFFF)
    return reverse_bits32(i)


@njit(cache=True, inline="always")
def owen_scramble(x, seed):
    """Nested uniform (Owen) scramble of the 32-bit fraction x (uint32) for ``seed``.

    Hash-based, after Burley 2020 ("Practical Hash-based Owen Scrambling"): reverse the bits,
    so digit j of the fraction (weight 2^-j) becomes bit j - 1; hash with steps that each
    change a bit only as a function of itself and the bits below it; reverse back. The steps:
    x += c (carries only go up), x ^= x * e with e even (bit b of x * e depends on bits < b
    only), x *= o with o odd (bit b becomes itself xor a function of bits < b). Each is a
    bijection of the 32-bit words, and under every one bit b is flipped by a function of
    the bits below it, so their composition flips digit j by a function of digits 1 .. j-1
    (and the seed) only: a nested scramble, which maps every elementary interval of the
    digits onto one, so it keeps (t, m, s)-nets nets. The seed enters through additions and
    through an odd and an even multiplier (the seed's own and its second word t = seed *
    OWEN_SEED_MUL, rotated so that other seed bits reach the low bits). Over random seeds
    the flips of the first three digits take all 2^7 patterns of a full nested uniform
    scramble equally often, and those of the first four digits 2^12 of its 2^15 (entropy),
    where an additive seed alone (Burley's hash) gives 2^3 and 2^4
    (tests/test_sampler.py)."""
    s = _U(seed) & MASK32
    t = (s * _SEED_MUL) & MASK32
    x = reverse_bits32(x)
    x = (x + s) & MASK32
    x ^= (x * _E0) & MASK32
    x = (x * (_rotr(s, _S16) | _ONE)) & MASK32
    x ^= (x * ((t << _S1) & MASK32)) & MASK32
    x = (x + _rotr(t, _S16)) & MASK32
    x ^= (x * _E1) & MASK32
    x = (x + _rotr(s, _S8)) & MASK32
    x ^= (x * _E2) & MASK32
    return reverse_bits32(x)


@njit(cache=True, inline="always")
def sobol_pair(index, seed_shuffle, seed_x, seed_y):
    """Sample ``index`` of an Owen-scrambled 2-D Sobol sequence, as (ux24, uy24).

    Burley's padding: the index is first shuffled by the nested scramble of its own bits
    (owen_scramble(index, seed_shuffle): bit b is flipped by a function of the bits above
    it), so each aligned block [k 2^m, (k + 1) 2^m) of indices maps onto an aligned block of
    Sobol indices, which is a (0, m, 2)-net; then each dimension is Owen-scrambled with its
    own seed, which keeps it a net; the top 24 bits are the u24s."""
    i = owen_scramble(index, seed_shuffle)
    ux = owen_scramble(sobol_u32(i, 0), seed_x) >> _S8
    uy = owen_scramble(sobol_u32(i, 1), seed_y) >> _S8
    return ux, uy


@njit(cache=True, inline="always")
def hash_u32(x, seed):
    """A 32-bit avalanche hash of x (uint32) keyed by ``seed``: xor-shift-multiply rounds
    (every step a bijection of the 32-bit words, so distinct x give distinct hashes)."""
    x = (_U(x) ^ _U(seed)) & MASK32
    x ^= x >> _S16
    x = (x * _H0) & MASK32
    x ^= x >> _S15
    x = (x * _H1) & MASK32
    x ^= x >> _S16
    return x


@njit(cache=True, inline="always")
def permute_index(i, n, seed):
    """Position of i (< n) in a random permutation of [0, n) chosen by ``seed``; n >= 1.

    A bijective hash of the b low bits (2^b the smallest power of two >= n; every step a
    bijection of them: xor and addition of keys, odd multiplications and xor-shifts of the
    masked bits downward), iterated until it lands in [0, n) (cycle walking: the orbit of i
    under a permutation of [0, 2^b) returns to [0, n), so this is a permutation of [0, n);
    fewer than 2 steps on average as n > 2^(b-1)), then rotated by a seed-chosen offset mod
    n (a bijection of the seed, times n, div 2^32), which makes each i's position uniform over
    seeds (to n 2^-32). The offset does not use hash_u32: hash_u32(c, seed) is the jitter of
    the stratified sampler's cells, which must not repeat the offset of the same seed."""
    i = _U(i) & MASK32
    n = _U(n) & MASK32
    s = _U(seed) & MASK32
    w = n - _ONE
    w |= w >> _S1
    w |= w >> _S2
    w |= w >> _S4
    w |= w >> _S8
    w |= w >> _S16
    while True:
        i ^= s
        i = (i * _P0) & MASK32
        i ^= (i & w) >> _S1
        i = (i + (s >> _S16)) & MASK32
        i = (i * _P1) & MASK32
        i ^= (i & w) >> _S3
        i ^= _rotr(s, _S8)
        i = (i * (_rotr(s, _S24) | _ONE)) & MASK32
        i ^= (i & w) >> _S2
        i = (i * _P2) & MASK32
        i ^= (i & w) >> _S6
        i &= w
        if i < n:
            break
    offset = (_rotr((s * _P0) & MASK32, _S16) * _P1) & MASK32   # a bijection of the seed
    return (i + ((offset * n) >> _S32)) % n


@njit(cache=True, inline="always")
def u24_in_stratum(f, cells, u32):
    """A u24 in [f / cells, (f + 1) / cells) (cells <= 2^24), placed by the uniform u32:
    the grid points of the stratum are ceil(f 2^24 / cells) .. ceil((f + 1) 2^24 / cells) - 1."""
    lo = (f * _2P24 + cells - _ONE) // cells
    hi = ((f + _ONE) * _2P24 + cells - _ONE) // cells
    return lo + (((u32 >> _S8) * (hi - lo)) >> _S24)


@njit(cache=True, inline="always")
def stratified_pair(index, n, seed_perm, seed_x, seed_y):
    """Sample ``index`` mod n of a correlated multi-jittered set of n, as (ux24, uy24).

    m = ceil(sqrt(n)) columns, rows = ceil(n / m). Sample s = index mod n takes cell
    c = permute_index(s, m rows, seed_perm) (column c mod m, row c div m; only n of the
    m rows cells are used). Within its column x falls in sub-column perm_row(row) of rows
    (permute_index with seed_x, one permutation for all columns), and within its row y in
    sub-row perm_col(col) of m (seed_y): the canonical multi-jitter of Chiu, Shirley and Wang
    (Kensler's correlated form). The x stratum is f = col rows + perm_row(row) of m rows,
    y's row m + perm_col(col); a hashed jitter (hash_u32 of the cell with seed_x, seed_y)
    places the point uniformly inside. The module docstring states the guarantees. The seeds
    do not depend on index div n: callers draw new seeds per epoch (sampler_pair does)."""
    nn = min(max(_U(n) & MASK32, _ONE), _MAX_N)
    m = _U(math.sqrt(float(nn)))
    while m * m < nn:
        m += _ONE
    while (m - _ONE) * (m - _ONE) >= nn:
        m -= _ONE
    rows = (nn + m - _ONE) // m
    cells = m * rows
    c = permute_index((_U(index) & MASK32) % nn, cells, seed_perm)
    col = c % m
    row = c // m
    fx = col * rows + permute_index(row, rows, seed_x)
    fy = row * m + permute_index(col, m, seed_y)
    ux = u24_in_stratum(fx, cells, hash_u32(c, seed_x))
    uy = u24_in_stratum(fy, cells, hash_u32(c, seed_y))
    return ux, uy


@njit(cache=True)
def sampler_pair(kind, key0, key1, pixel, index, pair, n):
    """Dimension pair ``pair`` of sample ``index`` of pixel ``pixel``, as (ux24, uy24).

    kind SAMPLER_SOBOL: sobol_pair with the seeds of Philox block (pair, pixel, 0,
    STREAM_SAMPLER) under key (key0, key1) (words 0, 1, 2: shuffle, x, y; n is ignored).
    kind SAMPLER_STRATIFIED: stratified_pair over n samples, with the seeds of block (pair,
    pixel, index div n, STREAM_SAMPLER) (words 0, 1, 2: permutation, x, y), so every epoch of
    n samples is a new stratified set. Any other kind (SAMPLER_INDEPENDENT, which the
    integrator serves from its own counter RNG instead) gets the top 24 bits of words 0 and
    1 of block (pair, pixel, index, STREAM_SAMPLER): independent uniforms (the same words
    as the stratified sampler's seeds for n = 1; a render uses one kind)."""
    if kind == SAMPLER_SOBOL:
        w0, w1, w2, w3 = philox4x32_10(pair, pixel, 0, STREAM_SAMPLER, key0, key1)
        return sobol_pair(index, w0, w1, w2)
    if kind == SAMPLER_STRATIFIED:
        nn = min(max(_U(n) & MASK32, _ONE), _MAX_N)
        epoch = (_U(index) & MASK32) // nn
        w0, w1, w2, w3 = philox4x32_10(pair, pixel, epoch, STREAM_SAMPLER, key0, key1)
        return stratified_pair(index, nn, w0, w1, w2)
    w0, w1, w2, w3 = philox4x32_10(pair, pixel, index, STREAM_SAMPLER, key0, key1)
    return w0 >> _S8, w1 >> _S8
