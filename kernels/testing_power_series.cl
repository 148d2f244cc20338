/* Test kernels for the power-series transmittance estimators: feed explicit rays, media and
 * seeds so tests/test_power_series.py can compare them with the Numba twins value by value. */

#include "params.h"
#include "rng.h"
#include "extinction.h"
#include "power_series.h"

/* kind: 0 unbiased ray marching, 1 p-series CMF. One work item per estimate; ray
 * r = i / n_per_ray uses sample index i % n_per_ray of stream STREAM_TEST, pixel r.
 * rays: RAY_STRIDE floats per ray (o.xyz, d.xyz, t0, t1, mbar, mu_c); meds: MED_SIZE floats
 * per ray, so one launch can mix profiles and a grid. counts: lookups, capped per estimate. */
#define RAY_STRIDE 10

kernel void t_power_series(int kind, global const float *meds, global const float *grid,
                           int3 dims, global const float *rays, int n_per_ray, ulong seed,
                           int max_steps, global float *out, global ulong *counts) {
    int i = get_global_id(0);
    int r = i / n_per_ray;
    global const float *ray = rays + RAY_STRIDE * r;
    float3 o = (float3)(ray[0], ray[1], ray[2]);
    float3 d = (float3)(ray[3], ray[4], ray[5]);
    Rng rng;
    rng_init(&rng, seed, (uint)r, (uint)(i % n_per_ray), STREAM_TEST);
    ulong cnt[N_COUNTERS];
    for (int k = 0; k < N_COUNTERS; ++k) cnt[k] = 0;
    global const float *med = meds + MED_SIZE * r;
    if (kind == 0)
        out[i] = transmittance_unbiased_raymarch(med, grid, dims, o, d, ray[6], ray[7], ray[8],
                                                 ray[9], &rng, cnt, max_steps);
    else
        out[i] = transmittance_power_series(med, grid, dims, o, d, ray[6], ray[7], ray[8],
                                            ray[9], &rng, cnt, max_steps);
    counts[2 * i] = cnt[C_LOOKUPS];
    counts[2 * i + 1] = cnt[C_CAPPED];
}
