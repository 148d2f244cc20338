/* Low-discrepancy sample pairs: Owen-scrambled Sobol points and correlated multi-jitter.
 * Twin of volmc/reference/sampler.py (the convention and the guarantees are written there),
 * bit for bit: integer arithmetic only. A pair is a uint2 of u24s: k means k * 2^-24
 * (multiply by UNIFORM_SCALE), like rng.h's uniforms. */
#ifndef VOLMC_SAMPLER_H
#define VOLMC_SAMPLER_H

#include "params.h" /* OWEN_*, HASH_*, PERM_*, SAMPLER_*, STREAM_SAMPLER (volmc/constants.py) */
#include "rng.h"

static inline uint reverse_bits32(uint x) {
    x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
    x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
    x = ((x >> 4) & 0x0F0F0F0Fu) | ((x & 0x0F0F0F0Fu) << 4);
    x = ((x >> 8) & 0x00FF00FFu) | ((x & 0x00FF00FFu) << 8);
    return (x >> 16) | (x << 16);
}

/* dim 0: van der Corput; any other dim: dimension 1 (polynomial x + 1: the Pascal matrix
 * mod 2, applied as a superset sum over the bit positions; sampler.py derives it). */
static inline uint sobol_u32(uint index, int dim) {
    if (dim == 0) return reverse_bits32(index);
    uint i = index;
    i ^= (i >> 1) & 0x55555555u;
    i ^= (i >> 2) & 0x33333333u;
    i ^= (i >> 4) & 0x0F0F0F0Fu;
    i ^= (i >> 8) & 0x00FF00FFu;
    i ^= (i >> 16) & 0x0000FFFFu;
    return reverse_bits32(i);
}

/* Nested uniform scramble: in the bit-reversed word every step flips a bit only as a function of
 * the bits below it (see sampler.py). rotate() rotates left: by 16, 24 = right by 16, 8. */
static inline uint owen_scramble(uint x, uint seed) {
    uint t = seed * OWEN_SEED_MUL;
    x = reverse_bits32(x);
    x += seed;
    x ^= x * OWEN_E0;
    x *= rotate(seed, 16u) | 1u;
    x ^= x * (t << 1);
    x += rotate(t, 16u);
    x ^= x * OWEN_E1;
    x += rotate(seed, 24u);
    x ^= x * OWEN_E2;
    return reverse_bits32(x);
}

static inline uint2 sobol_pair(uint index, uint seed_shuffle, uint seed_x, uint seed_y) {
    uint i = owen_scramble(index, seed_shuffle);
    return (uint2)(owen_scramble(sobol_u32(i, 0), seed_x) >> 8,
                   owen_scramble(sobol_u32(i, 1), seed_y) >> 8);
}

static inline uint hash_u32(uint x, uint seed) {
    x ^= seed;
    x ^= x >> 16;
    x *= HASH_M0;
    x ^= x >> 15;
    x *= HASH_M1;
    x ^= x >> 16;
    return x;
}

/* Random permutation of [0, n): a bijective hash of the low bits, cycle walking, a rotation. */
static inline uint permute_index(uint i, uint n, uint seed) {
    uint w = n - 1u;
    w |= w >> 1;
    w |= w >> 2;
    w |= w >> 4;
    w |= w >> 8;
    w |= w >> 16;
    do {
        i ^= seed;
        i *= PERM_M0;
        i ^= (i & w) >> 1;
        i += seed >> 16;
        i *= PERM_M1;
        i ^= (i & w) >> 3;
        i ^= rotate(seed, 24u);
        i *= rotate(seed, 8u) | 1u;
        i ^= (i & w) >> 2;
        i *= PERM_M2;
        i ^= (i & w) >> 6;
        i &= w;
    } while (i >= n);
    uint offset = rotate(seed * PERM_M0, 16u) * PERM_M1; /* not hash_u32: see sampler.py */
    return (i + (uint)(((ulong)offset * n) >> 32)) % n;
}

/* A u24 in stratum f of cells (cells <= 2^24), placed by the uniform word u32. */
static inline uint u24_in_stratum(uint f, uint cells, uint u32) {
    ulong lo = ((ulong)f * 0x1000000ul + cells - 1u) / cells;
    ulong hi = ((ulong)(f + 1u) * 0x1000000ul + cells - 1u) / cells;
    return (uint)(lo + (((ulong)(u32 >> 8) * (hi - lo)) >> 24));
}

static inline uint2 stratified_pair(uint index, uint n, uint seed_perm, uint seed_x, uint seed_y) {
    uint nn = clamp(n, 1u, (uint)SAMPLER_MAX_N);
    uint m = (uint)sqrt((float)nn);
    while (m * m < nn) ++m;
    while ((m - 1u) * (m - 1u) >= nn) --m;
    uint rows = (nn + m - 1u) / m;
    uint cells = m * rows;
    uint c = permute_index(index % nn, cells, seed_perm);
    uint col = c % m, row = c / m;
    uint fx = col * rows + permute_index(row, rows, seed_x);
    uint fy = row * m + permute_index(col, m, seed_y);
    return (uint2)(u24_in_stratum(fx, cells, hash_u32(c, seed_x)),
                   u24_in_stratum(fy, cells, hash_u32(c, seed_y)));
}

static inline uint2 sampler_pair(int kind, uint key0, uint key1, uint pixel, uint index, uint pair,
                                 uint n) {
    uint2 key = (uint2)(key0, key1);
    if (kind == SAMPLER_SOBOL) {
        uint4 w = philox4x32_10((uint4)(pair, pixel, 0u, STREAM_SAMPLER), key);
        return sobol_pair(index, w.x, w.y, w.z);
    }
    if (kind == SAMPLER_STRATIFIED) {
        uint nn = clamp(n, 1u, (uint)SAMPLER_MAX_N);
        uint4 w = philox4x32_10((uint4)(pair, pixel, index / nn, STREAM_SAMPLER), key);
        return stratified_pair(index, nn, w.x, w.y, w.z);
    }
    uint4 w = philox4x32_10((uint4)(pair, pixel, index, STREAM_SAMPLER), key);
    return (uint2)(w.x >> 8, w.y >> 8);
}

#endif
