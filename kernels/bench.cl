/* Lookup ceiling for `volmc bench render`: trilinear density lookups with no tracking logic.
 * Twin of volmc/bench/lookups.py (same hash, same points). Lane l of work-item i owns segment
 * i W + l (a pixel's camera ray clipped to the box, as the host prepared it) and, in each of
 * `passes` passes, looks the grid up at n_lookups evenly spaced points with a random offset:
 * the memory locality of a renderer whose lanes trace neighbouring pixels, and the lanes'
 * lookups in one vector, as the renderer's at the same width. */
#include "lanes.h"
#include "lane_io.h"
#include "grid.h"

/* 32-bit integer hash (a PCG output permutation): cheap, so the ceiling is the lookups'. */
static inline luint bench_hash(luint x) {
    luint s = x * 747796405u + 2891336453u;
    luint w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return (w >> 22u) ^ w;
}

kernel void lookup_throughput(global const float *grid, int4 dims, float4 bmin4, float4 bmax4,
                              global const float *segs, uint n_lookups, uint passes, uint seed,
                              global float *out, int n) {
    lmask on;
    lint gid = lane_element(n, &on);
    lvec3 o = load_float3(segs, gid, 8, 0), d = load_float3(segs, gid, 8, 3);
    lfloat t0 = load_float(segs, gid, 8, 6), len = load_float(segs, gid, 8, 7) - t0;
    float3 bmin = bmin4.xyz;
    float3 inv_extent = 1.0f / (bmax4.xyz - bmin);
    lfloat dt = len / (float)n_lookups;
    luint st = bench_hash(as_luint(gid) ^ bench_hash((luint)(seed)));
    lfloat acc = (lfloat)(0.0f);
    for (uint p = 0; p < passes; p++) {
        st = bench_hash(st);
        lfloat t = t0 + to_lfloat(st >> 8) * 0x1p-24f * dt;
        for (uint k = 0; k < n_lookups; k++)
            acc += grid_lookup(grid, dims.xyz, bmin, inv_extent, madd3(o, d, t + (float)k * dt), on);
    }
    store_float(out, gid, 1, 0, acc, on);
}
