/* Lookup ceiling for `volmc bench render`: trilinear density lookups with no tracking logic.
 * Twin of volmc/bench/lookups.py (same hash, same points). Work item i owns segment i (a
 * pixel's camera ray clipped to the box, as the host prepared it) and, in each of `passes`
 * passes, looks the grid up at n_lookups evenly spaced points with a random offset: the
 * memory locality of a renderer that keeps one pixel per work item. */
#include "grid.h"

/* 32-bit integer hash (a PCG output permutation): cheap, so the ceiling is the lookups'. */
static inline uint bench_hash(uint x) {
    uint s = x * 747796405u + 2891336453u;
    uint w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return (w >> 22u) ^ w;
}

kernel void lookup_throughput(global const float *grid, int4 dims, float4 bmin4, float4 bmax4,
                              global const float *segs, uint n_lookups, uint passes, uint seed,
                              global float *out) {
    uint gid = get_global_id(0);
    float3 o = vload3(0, segs + 8 * gid), d = vload3(1, segs + 8 * gid);
    float t0 = segs[8 * gid + 6], len = segs[8 * gid + 7] - t0;
    float3 bmin = bmin4.xyz;
    float3 inv_extent = 1.0f / (bmax4.xyz - bmin);
    float dt = len / (float)n_lookups;
    uint st = bench_hash(gid ^ bench_hash(seed));
    float acc = 0.0f;
    for (uint p = 0; p < passes; p++) {
        st = bench_hash(st);
        float t = t0 + (float)(st >> 8) * 0x1p-24f * dt;
        for (uint k = 0; k < n_lookups; k++)
            acc += grid_lookup(grid, dims.xyz, bmin, inv_extent, o + (t + (float)k * dt) * d);
    }
    out[gid] = acc;
}
