"""Philox4x32-10 counter-based generator: known answers, range, keys, uniformity."""

import numpy as np
import pytest
from numba import njit

from stats import ALPHA, chi2_pvalue, sidak
from volmc.reference.rng import (UNIFORM_SCALE, philox4x32_10, rng_new, rng_next,
                                 rng_next_u32, uniforms)

# Known-answer vectors of Random123's kat_vectors for philox4x32_10 (ctr, key -> out).
KAT = [
    ((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
    ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
    ((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0),
     (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1)),
]


@pytest.mark.parametrize("ctr,key,expected", KAT)
def test_philox_known_answers(ctr, key, expected):
    out = philox4x32_10(*ctr, *key)
    assert tuple(int(x) for x in out) == expected


def test_draws_are_lanes_of_consecutive_blocks():
    # Draw n is word n & 3 of block (n >> 2, pixel, sample, stream) keyed by the seed.
    seed, pix, smp, stream = (5 << 32) | 17, 123, 9, 1
    rng = rng_new(seed, pix, smp, stream)
    words = [int(rng_next_u32(rng)) for _ in range(12)]
    expected = []
    for block in range(3):
        expected += [int(x) for x in philox4x32_10(block, pix, smp, stream, 17, 5)]
    assert words == expected


def test_uniform_is_top_24_bits_and_never_one():
    # The largest possible word maps to 1 - 2^-24, strictly below 1.
    assert (0xFFFFFFFF >> 8) * UNIFORM_SCALE == 1.0 - 2.0**-24
    assert np.float32((0xFFFFFFFF >> 8) * UNIFORM_SCALE) < np.float32(1.0)
    u = uniforms(42, 7, 0, 0, 1 << 20)
    assert u.min() >= 0.0 and u.max() < 1.0
    # Every value is an exact multiple of 2^-24 (identical in float32 and float64).
    assert np.all(np.float64(np.float32(u)) == u)
    assert np.all(np.mod(u / UNIFORM_SCALE, 1.0) == 0.0)


def test_keys_give_different_streams():
    base = uniforms(1, 2, 3, 0, 64)
    for other in (uniforms(2, 2, 3, 0, 64), uniforms(1, 3, 3, 0, 64),
                  uniforms(1, 2, 4, 0, 64), uniforms(1, 2, 3, 1, 64)):
        assert not np.any(base == other) or np.mean(base == other) < 0.05
    assert np.array_equal(base, uniforms(1, 2, 3, 0, 64))


@njit(cache=True)
def _first_uniforms_over_pixels(n_pix, seed):
    out = np.empty(n_pix)
    for p in range(n_pix):
        rng = rng_new(seed, p, 0, 0)
        out[p] = rng_next(rng)
    return out


def test_uniformity_within_and_across_streams():
    """Chi-square over 256 equal bins: within one stream, and first draws across pixels."""
    a = sidak(ALPHA, 2)
    within = uniforms(3, 0, 0, 0, 1 << 20)
    across = _first_uniforms_over_pixels(1 << 18, 3)
    for u in (within, across):
        counts = np.bincount((u * 256).astype(int), minlength=256)
        p, _ = chi2_pvalue(counts, np.full(256, u.size / 256))
        assert p > a


def test_successive_pairs_are_independent():
    """2-D chi-square on (u_2k, u_2k+1): catches correlation between successive draws."""
    u = uniforms(11, 5, 2, 0, 1 << 21).reshape(-1, 2)
    bins = 32
    idx = (u * bins).astype(int)
    counts = np.bincount(idx[:, 0] * bins + idx[:, 1], minlength=bins * bins)
    p, _ = chi2_pvalue(counts, np.full(bins * bins, len(u) / bins**2))
    assert p > ALPHA
