"""Low-discrepancy sampler (volmc/reference/sampler.py, kernels/sampler.h): Sobol points,
Owen scrambling, the (0, m, 2)-nets of Burley's padding, the stratification guarantee of the
multi-jittered sampler, uniformity over seeds, and the kernels bit for bit."""

import math

import numpy as np
import pytest
from numba import njit

from stats import ALPHA, chi2_pvalue, sidak
from volmc.constants import (SAMPLER_INDEPENDENT, SAMPLER_MAX_N, SAMPLER_SOBOL,
                             SAMPLER_STRATIFIED)
from volmc.reference.sampler import (hash_u32, owen_scramble, permute_index, reverse_bits32,
                                     sampler_pair, sobol_pair, sobol_u32, stratified_pair)


KEY0, KEY1 = 0x9E3779B9, 0xF00DFACE   # a render seed with high bits set in both halves


@njit(cache=True)
def _pairs(kind, key0, key1, pixels, indices, pair, n):
    """sampler_pair over every (pixel, index): out[p, i] = (ux24, uy24)."""
    out = np.empty((pixels.size, indices.size, 2), np.int64)
    for p in range(pixels.size):
        for i in range(indices.size):
            ux, uy = sampler_pair(kind, key0, key1, pixels[p], indices[i], pair, n)
            out[p, i, 0] = ux
            out[p, i, 1] = uy
    return out


@njit(cache=True)
def _scrambles(xs, seed):
    out = np.empty(xs.size, np.int64)
    for i in range(xs.size):
        out[i] = owen_scramble(xs[i], seed)
    return out


@njit(cache=True)
def _digit_flips(seeds, digits):
    """For each seed, the flips of digits 1..digits of owen_scramble as one code: for digit j
    and each prefix p of the digits above it, the output's digit j of input (p, 0, 0, ...)."""
    out = np.zeros(seeds.size, np.int64)
    for s in range(seeds.size):
        code = 0
        for j in range(1, digits + 1):
            for p in range(1 << (j - 1)):
                x = np.uint64(p) << np.uint64(33 - j) if j > 1 else np.uint64(0)
                y = owen_scramble(x, seeds[s])
                code = 2 * code + int((y >> np.uint64(32 - j)) & np.uint64(1))
        out[s] = code
    return out


def _grid(n):
    """The stratified sampler's m columns and rows for n samples."""
    m = math.isqrt(n - 1) + 1
    return m, -(-n // m)


def _chi2_uniform_2d(x24, y24, bins):
    counts = np.bincount((x24 * bins >> 24) * bins + (y24 * bins >> 24), minlength=bins * bins)
    return chi2_pvalue(counts, np.full(bins * bins, x24.size / bins**2))[0]


# --- Sobol points ------------------------------------------------------------------------------

def test_sobol_u32_equals_scipy():
    """The first 2^12 unscrambled points of dims 0 and 1 are scipy's, bit for bit. scipy
    enumerates them in Gray-code order: its point i is Sobol index i ^ (i >> 1)."""
    from scipy.stats import qmc
    n = 1 << 12
    ref = qmc.Sobol(d=2, scramble=False, bits=32).random(n)
    ref = np.round(ref * 2.0**32).astype(np.uint64)
    gray = [i ^ (i >> 1) for i in range(n)]
    ours = np.array([[sobol_u32(g, 0), sobol_u32(g, 1)] for g in gray], np.uint64)
    assert np.array_equal(ours, ref)


def test_sobol_direction_numbers_follow_the_polynomial():
    """Dim 1's direction numbers are m_1 = 1, m_k = 2 m_{k-1} xor m_{k-1} (x + 1), for all
    32 bits; dim 0's are the bit reversal."""
    mk = 1
    for k in range(1, 33):
        assert int(sobol_u32(1 << (k - 1), 1)) == mk << (32 - k), k
        assert int(sobol_u32(1 << (k - 1), 0)) == 1 << (32 - k)
        mk = (mk << 1) ^ mk
    x = 0x12345678
    assert int(reverse_bits32(x)) == int(f"{x:032b}"[::-1], 2)


# --- Owen scrambling ---------------------------------------------------------------------------

@pytest.mark.parametrize("seed", [0, 1, 0xDEADBEEF, 0xFFFFFFFF])
def test_owen_scramble_is_a_nested_bijection(seed):
    """On 16-bit prefixes the scramble is a bijection, and the top 16 output bits depend on
    the top 16 input bits only (lower bits never change higher digits)."""
    k = np.arange(1 << 16, dtype=np.uint64)
    top = _scrambles(k << np.uint64(16), seed) >> 16
    assert np.array_equal(np.sort(top), np.arange(1 << 16))
    low = np.random.default_rng(seed % 1000).integers(0, 1 << 16, k.size).astype(np.uint64)
    assert np.array_equal(_scrambles((k << np.uint64(16)) | low, seed) >> 16, top)


def test_owen_scramble_top_digits_are_random():
    """Over random seeds the flips of the first three digits (7 flips: 1 + 2 + 4 prefixes) take
    all 2^7 patterns equally often (chi-square): on those digits the hash is a full nested
    uniform scramble. The flips of the first four digits (15) keep at least 11.8 bits of
    entropy (the design reaches 12; an additive seed alone, as in Burley's hash, gives 4)."""
    seeds = np.random.default_rng(7).integers(0, 2**32, 1 << 16).astype(np.uint64)
    counts = np.bincount(_digit_flips(seeds, 3), minlength=128)
    assert chi2_pvalue(counts, np.full(128, seeds.size / 128))[0] > ALPHA
    freq = np.bincount(_digit_flips(seeds, 4)) / seeds.size
    entropy = -np.sum(freq[freq > 0] * np.log2(freq[freq > 0]))
    assert entropy > 11.8, entropy


# --- Sobol pairs: nets -------------------------------------------------------------------------

def _is_net(x24, y24, m):
    """Every elementary interval of volume 2^-m (2^i x 2^j cells, i + j = m) holds one point."""
    for i in range(m + 1):
        cell = (x24 >> (24 - i)) << (m - i) | (y24 >> (24 - (m - i)))
        if not np.array_equal(np.bincount(cell, minlength=1 << m), np.ones(1 << m)):
            return False
    return True


@pytest.mark.parametrize("pixel,pair", [(0, 0), (1, 0), (77, 3), (2**32 - 1, 2**32 - 1)])
def test_sobol_pairs_are_nets(pixel, pair):
    """The indices [k 2^m, (k + 1) 2^m) of a pixel's pair form a (0, m, 2)-net, for m = 0..12,
    for the first block (k = 0) and later ones, up to the last block below 2^32."""
    for m in range(13):
        for k in (0, 1, 12345, (1 << (32 - m)) - 1):
            idx = np.arange(k << m, (k + 1) << m, dtype=np.uint64)
            p = _pairs(SAMPLER_SOBOL, KEY0, KEY1, np.array([pixel], np.uint64), idx, pair, 0)[0]
            assert _is_net(p[:, 0], p[:, 1], m), (m, k)


def test_sobol_pair_is_scrambled_sobol():
    """sobol_pair is the top 24 bits of owen_scramble(sobol_u32(shuffled index, dim), seed)
    with the index shuffled by owen_scramble(index, seed_shuffle)."""
    for seeds in [(0, 0, 0), (1, 2, 3), (0xFFFFFFFF, 0x80000000, 0x7FFFFFFF)]:
        for index in (0, 1, 5, 1000, 2**32 - 1):
            i = owen_scramble(index, seeds[0])
            want = (owen_scramble(sobol_u32(i, 0), seeds[1]) >> 8,
                    owen_scramble(sobol_u32(i, 1), seeds[2]) >> 8)
            assert tuple(int(v) for v in sobol_pair(index, *seeds)) == tuple(map(int, want))


# --- Sobol pairs: uniformity and independence over seeds ---------------------------------------

def test_sobol_points_uniform_over_pixels():
    """Chi-square on 64 x 64 cells: one sample index over 2^18 pixels (independent seeds) is
    uniform, for a first, a middle and a late index; and all 64 samples of 4096 pixels pooled."""
    pixels = np.arange(1 << 18, dtype=np.uint64)
    tests = [_pairs(SAMPLER_SOBOL, KEY0, KEY1, pixels, np.array([i], np.uint64), 1, 0)[:, 0]
             for i in (0, 37, 2**31 + 5)]
    tests.append(_pairs(SAMPLER_SOBOL, KEY0, KEY1, pixels[:4096],
                        np.arange(64, dtype=np.uint64), 0, 0).reshape(-1, 2))
    a = sidak(ALPHA, len(tests))
    for p in tests:
        assert _chi2_uniform_2d(p[:, 0], p[:, 1], 64) > a


def test_sobol_pairs_of_one_sample_are_independent():
    """2-D chi-square (32 x 32) on (pair 0 x, pair 1 x) and (pair 0 y, pair 5 y) of the same
    sample over 2^17 pixels, for three sample indices."""
    pixels = np.arange(1 << 17, dtype=np.uint64)
    a = sidak(ALPHA, 6)
    for i in (0, 3, 1000):
        idx = np.array([i], np.uint64)
        p0, p1, p5 = (_pairs(SAMPLER_SOBOL, KEY0, KEY1, pixels, idx, q, 0)[:, 0]
                      for q in (0, 1, 5))
        assert _chi2_uniform_2d(p0[:, 0], p1[:, 0], 32) > a
        assert _chi2_uniform_2d(p0[:, 1], p5[:, 1], 32) > a


# --- Stratified --------------------------------------------------------------------------------

@pytest.mark.parametrize("n", [1, 2, 3, 5, 7, 16, 17, 64, 100])
def test_stratification_guarantee(n):
    """For the samples of one epoch (index mod n = 0..n-1) of several pixels, pairs and epochs:
    n distinct cells of the m x rows grid, n distinct x and y strata of width 1 / (m rows);
    when n = m rows, exactly one sample in each 1/n interval of either axis."""
    m, rows = _grid(n)
    cells = m * rows
    for pixel, pair, epoch in [(0, 0, 0), (5, 1, 0), (123456, 2, 3), (2**32 - 1, 7, 1000)]:
        idx = np.arange(epoch * n, (epoch + 1) * n, dtype=np.uint64)
        p = _pairs(SAMPLER_STRATIFIED, KEY0, KEY1, np.array([pixel], np.uint64), idx, pair, n)[0]
        fx, fy = p[:, 0] * cells >> 24, p[:, 1] * cells >> 24
        assert np.unique(fx).size == n and np.unique(fy).size == n
        col, row = fx // rows, fy // m
        assert np.all(col < m) and np.all(row < rows)
        assert np.unique(col * rows + row).size == n
        if n == cells:
            for u in (p[:, 0], p[:, 1]):
                assert np.array_equal(np.sort(u * n >> 24), np.arange(n))


def test_stratified_epochs_differ():
    """Samples index and index + n come from different seeds (a new stratified set)."""
    n = 16
    idx = np.arange(4 * n, dtype=np.uint64)
    p = _pairs(SAMPLER_STRATIFIED, KEY0, KEY1, np.array([9], np.uint64), idx, 0, n)[0]
    for e in range(1, 4):
        assert not np.array_equal(p[:n], p[e * n:(e + 1) * n])


def test_stratified_grid_shapes():
    """m = ceil(sqrt(n)), rows = ceil(n / m), for n up to SAMPLER_MAX_N: the sampler's integer
    square root agrees with math.isqrt (its float sqrt is corrected both ways)."""
    for n in list(range(1, 2000)) + [SAMPLER_MAX_N - 1, SAMPLER_MAX_N, 4095**2, 4095**2 + 1]:
        m, rows = _grid(n)
        assert m * rows >= n and (m - 1) ** 2 < n <= m * m and rows <= m
    # The last cell of the largest grid still maps into the last stratum.
    p = sampler_pair(SAMPLER_STRATIFIED, KEY0, KEY1, 0, 2**32 - 1, 0, 2**32 - 1)
    assert all(0 <= int(v) < 1 << 24 for v in p)


@pytest.mark.parametrize("n", [3, 5, 17, 100])
def test_stratified_samples_uniform_over_pixels(n):
    """Each sample is uniform over seeds, including for n != m rows where cells stay empty:
    chi-square (16 x 16 cells) of sample index 0 and n - 1 over 2^16 pixels, and of all n
    samples of 2^16 / n pixels pooled."""
    pixels = np.arange(1 << 16, dtype=np.uint64)
    a = sidak(ALPHA, 3)
    for i in (0, n - 1):
        p = _pairs(SAMPLER_STRATIFIED, KEY0, KEY1, pixels, np.array([i], np.uint64), 2, n)[:, 0]
        assert _chi2_uniform_2d(p[:, 0], p[:, 1], 16) > a
    p = _pairs(SAMPLER_STRATIFIED, KEY0, KEY1, pixels[:(1 << 16) // n],
               np.arange(n, dtype=np.uint64), 2, n).reshape(-1, 2)
    assert _chi2_uniform_2d(p[:, 0], p[:, 1], 16) > a


@pytest.mark.parametrize("n", list(range(1, 70)) + [255, 256, 257, 1000, 4097, 65537])
def test_permute_index_is_a_permutation(n):
    for seed in (0, 1, 0xC0FFEE, 0xFFFFFFFF):
        perm = [int(permute_index(i, n, seed)) for i in range(n)]
        assert sorted(perm) == list(range(n)), (n, seed)


def test_permute_index_position_uniform_over_seeds():
    """Chi-square: permute_index(i, n, seed) over 2^15 seeds is uniform on [0, n)."""
    seeds = np.random.default_rng(5).integers(0, 2**32, 1 << 15)
    cases = [(n, i) for n in (2, 3, 6, 20) for i in (0, n - 1)]
    a = sidak(ALPHA, len(cases))
    for n, i in cases:
        counts = np.bincount([int(permute_index(i, n, s)) for s in seeds], minlength=n)
        assert chi2_pvalue(counts, np.full(n, seeds.size / n))[0] > a, (n, i)


def test_independent_kind_is_philox_words():
    from volmc.constants import STREAM_SAMPLER
    from volmc.reference.rng import philox4x32_10
    for pixel, index, pair in [(0, 0, 0), (3, 2**32 - 1, 9)]:
        w = philox4x32_10(pair, pixel, index, STREAM_SAMPLER, KEY0, KEY1)
        got = sampler_pair(SAMPLER_INDEPENDENT, KEY0, KEY1, pixel, index, pair, 4)
        assert (int(got[0]), int(got[1])) == (int(w[0]) >> 8, int(w[1]) >> 8)


# --- Kernels bit for bit -----------------------------------------------------------------------

def _edge_words(rng, count):
    w = rng.integers(0, 2**32, size=(count, 4), dtype=np.uint64)
    w[:8] = [[0, 0, 0, 0], [2**32 - 1] * 4, [1, 2**31, 2**24, 2**24 + 1],
             [2**31, 1, 4095**2 + 1, 7], [12345, 0xDEADBEEF, 99, 0], [2**32 - 2, 3, 5, 2**32 - 1],
             [0x80000001, 0x7FFFFFFF, 16, 17], [2**24 - 1, 2**16, 2**16 + 1, 100]]
    return w


def test_kernel_sampler_parts_identical(lanes):
    from cl_harness import out_buf, run, to_dev
    w = _edge_words(np.random.default_rng(11), 4096)
    out, ob = out_buf((len(w), 9), np.uint32)
    run("t_sampler_parts", len(w), to_dev(w.astype(np.uint32).ravel()), ob, outs=[(out, ob)])
    for row, (a, b, c, d) in zip(out, w):
        a, b, c, d = int(a), int(b), int(c), int(d)
        npm = c % 4096 + 1
        ref = [sobol_u32(a, 0), sobol_u32(a, 1), owen_scramble(a, b), hash_u32(a, b),
               permute_index(a % npm, npm, b), *sobol_pair(a, b, c, d),
               *stratified_pair(a, c, b, d, a ^ b)]
        assert [int(v) for v in row] == [int(v) for v in ref], (a, b, c, d)


def test_kernel_sampler_pairs_identical(lanes):
    from cl_harness import out_buf, run, to_dev
    rng = np.random.default_rng(12)
    count = 6000
    rows = np.empty((count, 7), np.uint64)
    rows[:, 0] = rng.choice([SAMPLER_INDEPENDENT, SAMPLER_STRATIFIED, SAMPLER_SOBOL, 7], count)
    rows[:, 1:6] = rng.integers(0, 2**32, size=(count, 5), dtype=np.uint64)
    rows[::2, 4] %= 1 << 12                         # small indices too, and small pixels/pairs
    rows[::3, 3] %= 1 << 16
    rows[::3, 5] %= 8
    rows[:, 6] = rng.choice([0, 1, 2, 3, 5, 7, 16, 17, 64, 100, 4096, SAMPLER_MAX_N,
                             SAMPLER_MAX_N + 3, 2**32 - 1], count)
    out, ob = out_buf((count, 2), np.uint32)
    run("t_sampler_pairs", count, to_dev(rows.astype(np.uint32).ravel()), ob, outs=[(out, ob)])
    for got, r in zip(out, rows):
        kind, *rest = (int(v) for v in r)
        ref = sampler_pair(kind, *rest)
        assert (int(got[0]), int(got[1])) == (int(ref[0]), int(ref[1])), r
