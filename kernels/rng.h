/* Counter-based random numbers: Philox4x32-10 keyed by (seed, pixel, sample, stream).
 * Twin of volmc/reference/rng.py; the convention is written there:
 *   key = (seed lo, seed hi), counter = (n >> 2, pixel, sample, stream);
 *   draw n = word (n & 3) of that block; uniform = (word >> 8) * 2^-24 in [0, 1 - 2^-24].
 * Uniforms are exact in float32, identical to the reference's and never 1.0. */
#ifndef VOLMC_RNG_H
#define VOLMC_RNG_H

#define PHILOX_M0 0xD2511F53u
#define PHILOX_M1 0xCD9E8D57u
#define PHILOX_W0 0x9E3779B9u
#define PHILOX_W1 0xBB67AE85u
#define PHILOX_ROUNDS 10
#define UNIFORM_SCALE 5.9604644775390625e-8f /* 2^-24 */

#define STREAM_PATH 0u
#define STREAM_SHADOW 1u
#define STREAM_TEST 2u

/* Mirrors the reference's uint32 state array [key0, key1, pixel, sample, stream, n, w0..w3]. */
typedef struct {
    uint key[2];
    uint ctr[3]; /* pixel, sample, stream */
    uint n;      /* index of the next draw */
    uint buf[4]; /* current block */
} Rng;

inline uint4 philox4x32_10(uint4 c, uint2 k) {
    for (int r = 0; r < PHILOX_ROUNDS; ++r) {
        if (r > 0) {
            k.x += PHILOX_W0;
            k.y += PHILOX_W1;
        }
        uint hi0 = mul_hi(PHILOX_M0, c.x);
        uint lo0 = PHILOX_M0 * c.x;
        uint hi1 = mul_hi(PHILOX_M1, c.z);
        uint lo1 = PHILOX_M1 * c.z;
        c = (uint4)(hi1 ^ c.y ^ k.x, lo1, hi0 ^ c.w ^ k.y, lo0);
    }
    return c;
}

inline void rng_init(Rng *rng, ulong seed, uint pixel, uint sample, uint stream) {
    rng->key[0] = (uint)(seed & 0xFFFFFFFFul);
    rng->key[1] = (uint)(seed >> 32);
    rng->ctr[0] = pixel;
    rng->ctr[1] = sample;
    rng->ctr[2] = stream;
    rng->n = 0u;
}

inline uint rng_next_u32(Rng *rng) {
    uint lane = rng->n & 3u;
    if (lane == 0u) {
        uint4 w = philox4x32_10((uint4)(rng->n >> 2, rng->ctr[0], rng->ctr[1], rng->ctr[2]),
                                (uint2)(rng->key[0], rng->key[1]));
        rng->buf[0] = w.x;
        rng->buf[1] = w.y;
        rng->buf[2] = w.z;
        rng->buf[3] = w.w;
    }
    rng->n += 1u;
    return rng->buf[lane];
}

inline float rng_next(Rng *rng) {
    return (float)(rng_next_u32(rng) >> 8) * UNIFORM_SCALE;
}

#endif
