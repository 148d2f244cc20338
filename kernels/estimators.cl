/* Batch transmittance estimation for tests and `volmc bench transmittance`.
 * Built with -DESTIMATOR=<function name> from estimators.h or power_series.h, so the
 * timed loop contains exactly one technique. Work item i estimates ray i / n_per_ray with
 * sample index i % n_per_ray on STREAM_TEST; rays are 9 floats: o(3), d(3), t0, t1, pad;
 * each ray has its own extinction source med[r * MED_SIZE ...] and (mbar, mu_c) bounds.
 * ESTIMATOR_EXTRA appends estimator-specific arguments (e.g. biased ray marching's
 * samples per mean free path). Per-estimate counters go to counters_out[i][N_COUNTERS]. */

#include "params.h"
#include "rng.h"
#include "extinction.h"
#include "estimators.h"
#include "power_series.h"

#ifndef ESTIMATOR_EXTRA
#define ESTIMATOR_EXTRA
#endif

kernel void estimate_batch(global const float *med, global const float *grid, int3 dims,
                           global const float *rays, global const float *bounds, int n_per_ray,
                           ulong seed, uint sample_offset, int max_steps, global float *out,
                           global ulong *counters_out) {
    int i = get_global_id(0);
    int r = i / n_per_ray;
    float3 o = vload3(3 * r, rays), d = vload3(3 * r + 1, rays);
    float t0 = rays[9 * r + 6], t1 = rays[9 * r + 7];
    float mbar = bounds[2 * r], mu_c = bounds[2 * r + 1];
    Rng rng;
    rng_init(&rng, seed, (uint)r, sample_offset + (uint)(i % n_per_ray), STREAM_TEST);
    ulong cnt[N_COUNTERS];
    for (int k = 0; k < N_COUNTERS; ++k) cnt[k] = 0;
    out[i] = ESTIMATOR(med + (size_t)r * MED_SIZE, grid, dims, o, d, t0, t1, mbar, mu_c, &rng, cnt,
                       max_steps ESTIMATOR_EXTRA);
    for (int k = 0; k < N_COUNTERS; ++k) counters_out[(size_t)i * N_COUNTERS + k] = cnt[k];
}
