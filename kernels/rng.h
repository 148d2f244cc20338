/* Counter-based random numbers: Philox4x32-10 keyed by (seed, pixel, sample, stream).
 * Twin of volmc/reference/rng.py; the convention is written there:
 *   key = (seed lo, seed hi), counter = (n >> 2, pixel, sample, stream);
 *   draw n = word (n & 3) of that block; uniform = (word >> 8) * 2^-24 in [0, 1 - 2^-24].
 * Uniforms are exact in float32, identical to the reference's and never 1.0. */
#ifndef VOLMC_RNG_H
#define VOLMC_RNG_H

#include "params.h" /* PHILOX_*, UNIFORM_SCALE, STREAM_* (volmc/constants.py) */

/* Mirrors the reference's uint32 state array [key0, key1, pixel, sample, stream, n, w0..w3]. */
typedef struct {
    uint key[2];
    uint ctr[3]; /* pixel, sample, stream */
    uint n;      /* index of the next draw */
    uint4 buf;   /* current block */
    uint preset; /* 1: the next draw is `word` (rng_preset) */
    uint word;
} Rng;

/* One Philox round on scalar words: a 32x32->64 multiplication gives hi and lo at once. */
#define PHILOX_ROUND(c0, c1, c2, c3, k0, k1)                      \
    do {                                                          \
        ulong p0_ = (ulong)PHILOX_M0 * (ulong)(c0);               \
        ulong p1_ = (ulong)PHILOX_M1 * (ulong)(c2);               \
        uint n0_ = (uint)(p1_ >> 32) ^ (c1) ^ (k0);               \
        uint n2_ = (uint)(p0_ >> 32) ^ (c3) ^ (k1);               \
        (c1) = (uint)p1_;                                         \
        (c3) = (uint)p0_;                                         \
        (c0) = n0_;                                               \
        (c2) = n2_;                                               \
    } while (0)

static inline uint4 philox4x32_10(uint4 c, uint2 k) {
    uint c0 = c.x, c1 = c.y, c2 = c.z, c3 = c.w, k0 = k.x, k1 = k.y;
    PHILOX_ROUND(c0, c1, c2, c3, k0, k1);
#pragma unroll
    for (int r = 1; r < PHILOX_ROUNDS; ++r) {
        k0 += PHILOX_W0;
        k1 += PHILOX_W1;
        PHILOX_ROUND(c0, c1, c2, c3, k0, k1);
    }
    return (uint4)(c0, c1, c2, c3);
}

static inline void rng_init(Rng *rng, ulong seed, uint pixel, uint sample, uint stream) {
    rng->key[0] = (uint)(seed & 0xFFFFFFFFul);
    rng->key[1] = (uint)(seed >> 32);
    rng->ctr[0] = pixel;
    rng->ctr[1] = sample;
    rng->ctr[2] = stream;
    rng->n = 0u;
    rng->preset = 0u;
}

/* The next draw returns u24 * 2^-24 (twin in rng.py, which says why). */
static inline void rng_preset(Rng *rng, uint u24) {
    rng->preset = 1u;
    rng->word = u24 << 8;
}

static inline void rng_drop_preset(Rng *rng) { rng->preset = 0u; }

static inline uint rng_next_u32(Rng *rng) {
    if (rng->preset) {
        rng->preset = 0u;
        return rng->word;
    }
    uint lane = rng->n & 3u;
    if (lane == 0u) {
        rng->buf = philox4x32_10((uint4)(rng->n >> 2, rng->ctr[0], rng->ctr[1], rng->ctr[2]),
                                 (uint2)(rng->key[0], rng->key[1]));
    }
    rng->n += 1u;
    /* Select the lane without indexing private memory dynamically (keeps Rng in registers). */
    uint4 b = rng->buf;
    return lane < 2u ? (lane == 0u ? b.x : b.y) : (lane == 2u ? b.z : b.w);
}

static inline float rng_next(Rng *rng) {
    return (float)(rng_next_u32(rng) >> 8) * UNIFORM_SCALE;
}

#endif
