/* Per-lane loads and stores for the test and benchmark kernels (not the renderer's: no twin).
 * Lane l of work-item i handles element e = i W + l of a batch of n; lanes past n are
 * inactive, read element 0 and write nothing. Each element is read and written exactly as
 * the scalar kernels' one work-item per element did, so a test gives the same numbers at
 * every width. */
#ifndef VOLMC_LANE_IO_H
#define VOLMC_LANE_IO_H

#include "lanes.h"

/* This lane's element of a batch of n (0 where inactive); writes the active lanes. */
static inline lint lane_element(int n, lmask *active) {
    lint e = (lint)((int)get_global_id(0) * LANES) + LANE_IOTA;
    *active = e < n;
    return select((lint)(0), e, *active);
}

/* a[k i + j] per lane (k floats per element, j the one wanted). */
static inline lfloat load_float(global const float *a, lint i, int k, int j) {
    return gather_float(a, k * i + j);
}

static inline lvec3 load_float3(global const float *a, lint i, int k, int j) {
    return v3(gather_float(a, k * i + j), gather_float(a, k * i + j + 1),
              gather_float(a, k * i + j + 2));
}

static inline luint load_uint(global const uint *a, lint i, int k, int j) {
    return as_luint(gather_int((global const int *)a, k * i + j));
}

static inline void store_float(global float *a, lint i, int k, int j, lfloat v, lmask m) {
    for (int l = 0; l < LANES; ++l)
        if (lane_on(m, l)) a[(size_t)k * lane_int(i, l) + j] = lane_float(v, l);
}

static inline void store_float3(global float *a, lint i, int k, int j, lvec3 v, lmask m) {
    store_float(a, i, k, j, v.x, m);
    store_float(a, i, k, j + 1, v.y, m);
    store_float(a, i, k, j + 2, v.z, m);
}

static inline void store_uint(global uint *a, lint i, int k, int j, luint v, lmask m) {
    for (int l = 0; l < LANES; ++l)
        if (lane_on(m, l)) a[(size_t)k * lane_int(i, l) + j] = lane_uint(v, l);
}

static inline void store_ulong(global ulong *a, lint i, int k, int j, lulong v, lmask m) {
    LaneUlongs u;
    u.v = v;
    for (int l = 0; l < LANES; ++l)
        if (lane_on(m, l)) a[(size_t)k * lane_int(i, l) + j] = u.a[l];
}

/* Batches of rays with n_per_ray estimates each, where every ray may have its own medium
 * (the medium is the same for all lanes): work-item i covers estimates [c W, (c + 1) W) of
 * ray r, with ceil(n_per_ray / W) work-items per ray (the host launches n_rays times that).
 * Returns the lanes' estimate indices within the ray; writes r and the active lanes. */
static inline lint ray_lanes(int n_per_ray, int *r, lmask *active) {
    int per = (n_per_ray + LANES - 1) / LANES;
    int i = (int)get_global_id(0);
    *r = i / per;
    lint j = (lint)((i - *r * per) * LANES) + LANE_IOTA;
    *active = j < n_per_ray;
    return select((lint)(0), j, *active);
}

#endif
