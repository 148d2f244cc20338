/* Batch transmittance estimation for tests and `volmc bench transmittance`.
 * Built with -DESTIMATOR=<function name> (volmc/techniques.py), so the timed loop contains
 * exactly one technique. Estimate j of ray r goes to slot r n_per_ray + j and uses sample
 * index sample_offset + j on STREAM_TEST, pixel r; the lanes of a work-item estimate the
 * same ray (ray_lanes in lane_io.h: the host launches n_rays ceil(n_per_ray / W) work-items).
 * Rays are 9 floats: o(3), d(3), t0, t1, pad; ray r goes through medium record media[r] (its
 * majorant bounds included), all sharing the grid and majorant arrays (maj, mnr, and an
 * octree's nodes). Per-estimate counters go to counters_out[slot][N_COUNTERS]. Built with
 * FEATURE_CHROMATIC, out[slot] is the RGB estimate (3 floats); otherwise the media are grey
 * and out[slot] is the estimate. */

#include "params.h"
#include "lanes.h"
#include "lane_io.h"
#include "rng.h"
#include "medium.h"
#include "estimators.h"

kernel void estimate_batch(global const Medium *media, global const float *grid,
                           global const float *maj, global const float *mnr,
                           global const int *nodes, global const float *rays, int n_per_ray,
                           ulong seed, uint sample_offset, int max_steps, global float *out,
                           global ulong *counters_out) {
    int r;
    lmask on;
    lint j = ray_lanes(n_per_ray, &r, &on);
    if (!ANY(on)) return;
    MediumData med = {{media[r]}, grid, maj, mnr, grid, grid, 0, grid, nodes, 0, 0, (lint)(-1)};
    lvec3 o = v3u(vload3(3 * r, rays)), d = v3u(vload3(3 * r + 1, rays));
    lfloat t0 = (lfloat)(rays[9 * r + 6]), t1 = (lfloat)(rays[9 * r + 7]);
    Rng rng = rng_empty();
    rng_init(&rng, seed, (luint)(r), sample_offset + as_luint(j), STREAM_TEST, on);
    lulong cnt[N_COUNTERS];
    for (int k = 0; k < N_COUNTERS; ++k) cnt[k] = (lulong)(0);
    spec T = ESTIMATOR(&med, o, d, t0, t1, &rng, cnt, max_steps, on);
    lint idx = r * n_per_ray + j;
#if FEATURE_CHROMATIC
    store_float3(out, idx, 3, 0, T, on);
#else
    store_float(out, idx, 1, 0, T, on);
#endif
    for (int k = 0; k < N_COUNTERS; ++k) store_ulong(counters_out, idx, N_COUNTERS, k, cnt[k], on);
}
