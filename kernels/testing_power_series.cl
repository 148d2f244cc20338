/* Test kernels for the power-series transmittance estimators: feed explicit rays, media and
 * seeds so tests/test_power_series.py can compare them with the Numba twins value by value. */

#include "params.h"
#include "lanes.h"
#include "lane_io.h"
#include "rng.h"
#include "medium.h"
#include "power_series.h"

/* kind: 0 unbiased ray marching, 1 p-series CMF, on one segment. Estimate j of ray r (the
 * lanes of a work-item share a ray: ray_lanes) uses sample index j of stream STREAM_TEST,
 * pixel r, and goes to r n_per_ray + j. rays: 10 floats per ray (o.xyz, d.xyz, t0, t1, mbar,
 * mu_c); media: one medium record per ray, so one launch can mix profiles and a grid.
 * counts: lookups, capped per estimate. */
kernel void t_power_series(int kind, global const Medium *media, global const float *grid,
                           global const float *rays, int n_per_ray, ulong seed,
                           int max_steps, global float *out, global ulong *counts, int n) {
    int r;
    lmask on;
    lint j = ray_lanes(n_per_ray, &r, &on);
    if (!ANY(on)) return;
    global const float *ray = rays + 10 * r;
    MediumData med = {{media[r]}, grid, grid, grid, grid, grid, 0, grid, 0, 0, 0, (lint)(-1)};
    lvec3 o = v3((lfloat)(ray[0]), (lfloat)(ray[1]), (lfloat)(ray[2]));
    lvec3 d = v3((lfloat)(ray[3]), (lfloat)(ray[4]), (lfloat)(ray[5]));
    Rng rng = rng_empty();
    rng_init(&rng, seed, (luint)(r), as_luint(j), STREAM_TEST, on);
    lulong cnt[N_COUNTERS];
    for (int k = 0; k < N_COUNTERS; ++k) cnt[k] = (lulong)(0);
    lfloat T;
    if (kind == 0)
        T = unbiased_raymarch_segment(&med, o, d, (lfloat)(ray[6]), (lfloat)(ray[7]),
                                      (lfloat)(ray[8]), (lfloat)(ray[9]), &rng, cnt, max_steps, on);
    else
        T = power_series_segment(&med, o, d, (lfloat)(ray[6]), (lfloat)(ray[7]), (lfloat)(ray[8]),
                                 (lfloat)(ray[9]), &rng, cnt, max_steps, on);
    lint idx = r * n_per_ray + j;
    store_float(out, idx, 1, 0, T, on);
    store_ulong(counts, idx, 2, 0, cnt[C_LOOKUPS], on);
    store_ulong(counts, idx, 2, 1, cnt[C_CAPPED], on);
}
