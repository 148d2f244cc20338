/* Low-discrepancy sample pairs: Owen-scrambled Sobol points and correlated multi-jitter.
 * Twin of volmc/reference/sampler.py (the convention and the guarantees are written there),
 * bit for bit: integer arithmetic only. A pair is two u24s per lane: k means k * 2^-24
 * (multiply by UNIFORM_SCALE), like rng.h's uniforms. The point set (n, the strata) is the
 * same in every lane; the pixel, the index and the pair vary. */
#ifndef VOLMC_SAMPLER_H
#define VOLMC_SAMPLER_H

#include "params.h" /* OWEN_*, HASH_*, PERM_*, SAMPLER_*, STREAM_SAMPLER (volmc/constants.py) */
#include "lanes.h"
#include "rng.h"

/* Two u24s per lane. */
typedef struct {
    luint x, y;
} LanePair;

static inline luint reverse_bits32(luint x) {
    x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
    x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
    x = ((x >> 4) & 0x0F0F0F0Fu) | ((x & 0x0F0F0F0Fu) << 4);
    x = ((x >> 8) & 0x00FF00FFu) | ((x & 0x00FF00FFu) << 8);
    return (x >> 16) | (x << 16);
}

/* dim 0: van der Corput; any other dim: dimension 1 (polynomial x + 1: the Pascal matrix
 * mod 2, applied as a superset sum over the bit positions; sampler.py derives it). */
static inline luint sobol_u32(luint index, int dim) {
    if (dim == 0) return reverse_bits32(index);
    luint i = index;
    i ^= (i >> 1) & 0x55555555u;
    i ^= (i >> 2) & 0x33333333u;
    i ^= (i >> 4) & 0x0F0F0F0Fu;
    i ^= (i >> 8) & 0x00FF00FFu;
    i ^= (i >> 16) & 0x0000FFFFu;
    return reverse_bits32(i);
}

/* Nested uniform scramble: in the bit-reversed word every step flips a bit only as a function of
 * the bits below it (see sampler.py). rotate() rotates left: by 16, 24 = right by 16, 8. */
static inline luint owen_scramble(luint x, luint seed) {
    luint t = seed * OWEN_SEED_MUL;
    x = reverse_bits32(x);
    x += seed;
    x ^= x * OWEN_E0;
    x *= rotate(seed, (luint)(16u)) | 1u;
    x ^= x * (t << 1);
    x += rotate(t, (luint)(16u));
    x ^= x * OWEN_E1;
    x += rotate(seed, (luint)(24u));
    x ^= x * OWEN_E2;
    return reverse_bits32(x);
}

static inline LanePair sobol_pair(luint index, luint seed_shuffle, luint seed_x, luint seed_y) {
    luint i = owen_scramble(index, seed_shuffle);
    LanePair r = {owen_scramble(sobol_u32(i, 0), seed_x) >> 8,
                  owen_scramble(sobol_u32(i, 1), seed_y) >> 8};
    return r;
}

static inline luint hash_u32(luint x, luint seed) {
    x ^= seed;
    x ^= x >> 16;
    x *= HASH_M0;
    x ^= x >> 15;
    x *= HASH_M1;
    x ^= x >> 16;
    return x;
}

/* Random permutation of [0, n): a bijective hash of the low bits, cycle walking (each lane
 * until its value falls below n), a rotation. */
static inline luint permute_index(luint i, uint n, luint seed) {
    uint w = n - 1u;
    w |= w >> 1;
    w |= w >> 2;
    w |= w >> 4;
    w |= w >> 8;
    w |= w >> 16;
    lmask walking = LANES_ALL;
    do {
        luint j = i ^ seed;
        j *= PERM_M0;
        j ^= (j & w) >> 1;
        j += seed >> 16;
        j *= PERM_M1;
        j ^= (j & w) >> 3;
        j ^= rotate(seed, (luint)(24u));
        j *= rotate(seed, (luint)(8u)) | 1u;
        j ^= (j & w) >> 2;
        j *= PERM_M2;
        j ^= (j & w) >> 6;
        j &= w;
        i = select(i, j, walking);
        walking = walking & (i >= n);
    } while (ANY(walking));
    luint offset = rotate(seed * PERM_M0, (luint)(16u)) * PERM_M1; /* not hash_u32: see sampler.py */
    return (i + mul_hi(offset, (luint)(n))) % n;
}

/* A u24 in stratum f of cells (cells <= 2^24), placed by the uniform word u32. */
static inline luint u24_in_stratum(luint f, uint cells, luint u32) {
    lulong lo = (to_lulong(f) * 0x1000000ul + (cells - 1u)) / cells;
    lulong hi = (to_lulong(f + 1u) * 0x1000000ul + (cells - 1u)) / cells;
    return to_luint(lo + ((to_lulong(u32 >> 8) * (hi - lo)) >> 24));
}

static inline LanePair stratified_pair(luint index, uint n, luint seed_perm, luint seed_x,
                                       luint seed_y) {
    uint nn = clamp(n, 1u, (uint)SAMPLER_MAX_N);
    uint m = (uint)sqrt((float)nn);
    while (m * m < nn) ++m;
    while ((m - 1u) * (m - 1u) >= nn) --m;
    uint rows = (nn + m - 1u) / m;
    uint cells = m * rows;
    luint c = permute_index(index % nn, cells, seed_perm);
    luint col = c % m, row = c / m;
    luint fx = col * rows + permute_index(row, rows, seed_x);
    luint fy = row * m + permute_index(col, m, seed_y);
    LanePair r = {u24_in_stratum(fx, cells, hash_u32(c, seed_x)),
                  u24_in_stratum(fy, cells, hash_u32(c, seed_y))};
    return r;
}

static inline LanePair sampler_pair(int kind, uint key0, uint key1, luint pixel, luint index,
                                    luint pair, uint n) {
    if (kind == SAMPLER_SOBOL) {
        LaneWords w = philox4x32_10(pair, pixel, (luint)(0u), (luint)(STREAM_SAMPLER), key0,
                                    key1);
        return sobol_pair(index, w.x, w.y, w.z);
    }
    if (kind == SAMPLER_STRATIFIED) {
        uint nn = clamp(n, 1u, (uint)SAMPLER_MAX_N);
        LaneWords w = philox4x32_10(pair, pixel, index / nn, (luint)(STREAM_SAMPLER), key0,
                                    key1);
        return stratified_pair(index, nn, w.x, w.y, w.z);
    }
    LaneWords w = philox4x32_10(pair, pixel, index, (luint)(STREAM_SAMPLER), key0, key1);
    LanePair r = {w.x >> 8, w.y >> 8};
    return r;
}

#endif
