/* Counter-based random numbers: Philox4x32-10 keyed by (seed, pixel, sample, stream).
 * Twin of volmc/reference/rng.py; the convention is written there:
 *   key = (seed lo, seed hi), counter = (n >> 2, pixel, sample, stream);
 *   draw n = word (n & 3) of that block; uniform = (word >> 8) * 2^-24 in [0, 1 - 2^-24].
 * Uniforms are exact in float32, identical to the reference's and never 1.0.
 * Per lane (lanes.h): each lane is its own stream (its pixel, sample, stream id and draw
 * index); the seed is the same in every lane. A draw advances only the lanes it is asked
 * for, so a lane draws exactly the numbers the scalar stream would. */
#ifndef VOLMC_RNG_H
#define VOLMC_RNG_H

#include "params.h" /* PHILOX_*, UNIFORM_SCALE, STREAM_* (volmc/constants.py) */
#include "lanes.h"

/* With several lanes, one Philox call fills every lane's next block: the lanes' draw indices
 * drift apart, so without it nearly every draw finds some lane at a block boundary and runs
 * Philox for all, a quarter of them useful. The prefetch (p0..p3, the block (n + 3) >> 2 that
 * lane refills from next) keeps the numbers as they are and measured 1.19x samples/s on the
 * default cloud at W = 16 and 1.07x at W = 8, but 0.96x at W = 1, where no call is wasted.
 * The reference has no counterpart: it changes when a block is computed, not its words. */
#ifndef RNG_PREFETCH
#define RNG_PREFETCH (LANES > 1)
#endif

/* Mirrors the reference's uint32 state array [key0, key1, pixel, sample, stream, n, w0..w3,
 * preset, word]. */
typedef struct {
    uint key0, key1;
    luint pixel, sample, stream;
    luint n;              /* index of the next draw */
    luint w0, w1, w2, w3; /* current block */
    lmask preset;         /* the next draw is `word` (rng_preset) */
    luint word;
#if RNG_PREFETCH
    luint p0, p1, p2, p3; /* block (n + 3) >> 2, the next one a lane refills from */
    lmask ready;          /* p0..p3 hold it */
#endif
} Rng;

/* Four 32-bit words per lane. */
typedef struct {
    luint x, y, z, w;
} LaneWords;

static inline LaneWords philox4x32_10(luint c0, luint c1, luint c2, luint c3, uint k0,
                                      uint k1) {
#pragma unroll
    for (int r = 0; r < PHILOX_ROUNDS; ++r) {
        if (r > 0) {
            k0 += PHILOX_W0;
            k1 += PHILOX_W1;
        }
        /* The high half of the 32x32->64 multiplication from a 64-bit product (2.2x faster
         * than mul_hi on PoCL at W = 1, 1.5x at W = 16), the low half as a 32-bit one. */
        luint hi0 = to_luint((to_lulong(c0) * (ulong)PHILOX_M0) >> 32), lo0 = c0 * PHILOX_M0;
        luint hi1 = to_luint((to_lulong(c2) * (ulong)PHILOX_M1) >> 32), lo1 = c2 * PHILOX_M1;
        c0 = hi1 ^ c1 ^ k0;
        c1 = lo1;
        c2 = hi0 ^ c3 ^ k1;
        c3 = lo0;
    }
    LaneWords w = {c0, c1, c2, c3};
    return w;
}

/* Starts the stream in the active lanes; the others keep theirs. */
static inline void rng_init(Rng *rng, ulong seed, luint pixel, luint sample, uint stream,
                            lmask active) {
    rng->key0 = (uint)(seed & 0xFFFFFFFFul);
    rng->key1 = (uint)(seed >> 32);
    rng->stream = select(rng->stream, (luint)(stream), active);
    rng->pixel = select(rng->pixel, pixel, active);
    rng->sample = select(rng->sample, sample, active);
    rng->n = select(rng->n, (luint)(0u), active);
    rng->preset = rng->preset & !active;
#if RNG_PREFETCH
    rng->ready = rng->ready & !active;
#endif
}

/* A stream with no lane started: every field 0, so no preset draw and no prefetched block.
 * All of it, not just the masks: rng_swap reads every field of both streams, and with
 * rng_next inlined, PoCL (LLVM 15) at W = 1 dropped a test kernel's stores when some were
 * never written (tests/test_kernels.py, ragged draws). */
static inline Rng rng_empty(void) {
    Rng r = {0};
    return r;
}

/* The next draw of the active lanes returns u24 * 2^-24 (twin in rng.py, which says why). */
static inline void rng_preset(Rng *rng, luint u24, lmask active) {
    rng->preset = rng->preset | active;
    rng->word = select(rng->word, u24 << 8, active);
}

static inline void rng_drop_preset(Rng *rng, lmask active) {
    rng->preset = rng->preset & !active;
}

static inline __attribute__((always_inline)) luint rng_next_u32(Rng *rng, lmask active) {
    lmask taken = active & rng->preset;
    lmask draw = active & !rng->preset;
    luint word = rng->n & 3u;
    lmask refill = draw & (word == 0u);
#if RNG_PREFETCH
    if (ANY(refill & !rng->ready)) {
        LaneWords b = philox4x32_10((rng->n + 3u) >> 2, rng->pixel, rng->sample, rng->stream,
                                    rng->key0, rng->key1);
        lmask fill = !rng->ready;
        rng->p0 = select(rng->p0, b.x, fill);
        rng->p1 = select(rng->p1, b.y, fill);
        rng->p2 = select(rng->p2, b.z, fill);
        rng->p3 = select(rng->p3, b.w, fill);
        rng->ready = LANES_ALL;
    }
    rng->w0 = select(rng->w0, rng->p0, refill);
    rng->w1 = select(rng->w1, rng->p1, refill);
    rng->w2 = select(rng->w2, rng->p2, refill);
    rng->w3 = select(rng->w3, rng->p3, refill);
    rng->ready = rng->ready & !refill;
#else
    if (ANY(refill)) {
        LaneWords b = philox4x32_10(rng->n >> 2, rng->pixel, rng->sample, rng->stream,
                                    rng->key0, rng->key1);
        rng->w0 = select(rng->w0, b.x, refill);
        rng->w1 = select(rng->w1, b.y, refill);
        rng->w2 = select(rng->w2, b.z, refill);
        rng->w3 = select(rng->w3, b.w, refill);
    }
#endif
    rng->n += as_luint(draw & 1);
    rng->preset = rng->preset & !active;
    luint out = select(select(rng->w2, rng->w3, word == 3u), select(rng->w0, rng->w1, word == 1u),
                       word < 2u);
    return select(out, rng->word, taken);
}

/* Exchanges the streams of a and b in the lanes of m (a shadow ray's walk draws from the
 * stream its walk loop uses; kernels/integrator.cl). */
static inline void rng_swap(Rng *a, Rng *b, lmask m) {
#define RNG_SWAP_FIELD(T, f)              \
    {                                     \
        T x = a->f;                       \
        a->f = select(a->f, b->f, m);     \
        b->f = select(b->f, x, m);        \
    }
    RNG_SWAP_FIELD(luint, pixel)
    RNG_SWAP_FIELD(luint, sample)
    RNG_SWAP_FIELD(luint, stream)
    RNG_SWAP_FIELD(luint, n)
    RNG_SWAP_FIELD(luint, w0)
    RNG_SWAP_FIELD(luint, w1)
    RNG_SWAP_FIELD(luint, w2)
    RNG_SWAP_FIELD(luint, w3)
    RNG_SWAP_FIELD(luint, word)
    RNG_SWAP_FIELD(lmask, preset)
#if RNG_PREFETCH
    RNG_SWAP_FIELD(luint, p0)
    RNG_SWAP_FIELD(luint, p1)
    RNG_SWAP_FIELD(luint, p2)
    RNG_SWAP_FIELD(luint, p3)
    RNG_SWAP_FIELD(lmask, ready)
#endif
#undef RNG_SWAP_FIELD
}

static inline __attribute__((always_inline)) lfloat rng_next(Rng *rng, lmask active) {
    return to_lfloat(rng_next_u32(rng, active) >> 8) * UNIFORM_SCALE;
}

#endif
