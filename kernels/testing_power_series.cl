/* Test kernels for the power-series transmittance estimators: feed explicit rays, media and
 * seeds so tests/test_power_series.py can compare them with the Numba twins value by value. */

#include "params.h"
#include "rng.h"
#include "medium.h"
#include "power_series.h"

/* kind: 0 unbiased ray marching, 1 p-series CMF, on one segment. One work item per estimate;
 * ray r = i / n_per_ray uses sample index i % n_per_ray of stream STREAM_TEST, pixel r.
 * rays: 10 floats per ray (o.xyz, d.xyz, t0, t1, mbar, mu_c); media: one medium record per
 * ray, so one launch can mix profiles and a grid. counts: lookups, capped per estimate. */
kernel void t_power_series(int kind, global const Medium *media, global const float *grid,
                           global const float *rays, int n_per_ray, ulong seed,
                           int max_steps, global float *out, global ulong *counts) {
    int i = get_global_id(0);
    int r = i / n_per_ray;
    global const float *ray = rays + 10 * r;
    Medium m = media[r];
    MediumData med = {m, grid, grid, grid, grid, grid, 0, grid, 0, 0};
    float3 o = (float3)(ray[0], ray[1], ray[2]);
    float3 d = (float3)(ray[3], ray[4], ray[5]);
    Rng rng;
    rng_init(&rng, seed, (uint)r, (uint)(i % n_per_ray), STREAM_TEST);
    ulong cnt[N_COUNTERS];
    for (int k = 0; k < N_COUNTERS; ++k) cnt[k] = 0;
    if (kind == 0)
        out[i] = unbiased_raymarch_segment(&med, o, d, ray[6], ray[7], ray[8], ray[9], &rng, cnt,
                                           max_steps);
    else
        out[i] = power_series_segment(&med, o, d, ray[6], ray[7], ray[8], ray[9], &rng, cnt,
                                      max_steps);
    counts[2 * i] = cnt[C_LOOKUPS];
    counts[2 * i + 1] = cnt[C_CAPPED];
}
