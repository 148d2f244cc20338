/* Batch transmittance estimation for tests and `volmc bench transmittance`.
 * Built with -DESTIMATOR=<function name> (volmc/techniques.py), so the timed loop contains
 * exactly one technique. Work item i estimates ray i / n_per_ray with sample index
 * sample_offset + i % n_per_ray on STREAM_TEST; rays are 9 floats: o(3), d(3), t0, t1, pad;
 * ray r goes through medium record media[r] (its majorant bounds included), all sharing the
 * grid and majorant arrays (maj, mnr, and an octree's nodes). Per-estimate counters go to counters_out[i][N_COUNTERS]. Built
 * with FEATURE_CHROMATIC, out[i] is the RGB estimate (3 floats); otherwise the media are
 * grey and out[i] is the estimate. */

#include "params.h"
#include "rng.h"
#include "medium.h"
#include "estimators.h"

kernel void estimate_batch(global const Medium *media, global const float *grid,
                           global const float *maj, global const float *mnr,
                           global const int *nodes, global const float *rays, int n_per_ray, ulong seed,
                           uint sample_offset, int max_steps, global float *out,
                           global ulong *counters_out) {
    int i = get_global_id(0);
    int r = i / n_per_ray;
    Medium m = media[r];
    MediumData med = {m, grid, maj, mnr, grid, grid, 0, grid, nodes, 0};
    float3 o = vload3(3 * r, rays), d = vload3(3 * r + 1, rays);
    float t0 = rays[9 * r + 6], t1 = rays[9 * r + 7];
    Rng rng;
    rng_init(&rng, seed, (uint)r, sample_offset + (uint)(i % n_per_ray), STREAM_TEST);
    ulong cnt[N_COUNTERS];
    for (int k = 0; k < N_COUNTERS; ++k) cnt[k] = 0;
    spec T = ESTIMATOR(&med, o, d, t0, t1, &rng, cnt, max_steps);
#if FEATURE_CHROMATIC
    vstore3(T, i, out);
#else
    out[i] = T;
#endif
    for (int k = 0; k < N_COUNTERS; ++k) counters_out[(size_t)i * N_COUNTERS + k] = cnt[k];
}
