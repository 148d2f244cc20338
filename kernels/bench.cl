/* Lookup ceiling for `volmc bench render`: trilinear density lookups with no tracking logic.
 * Twin of volmc/bench/lookups.py (same hash, same points). Each work item draws two points
 * in the box and looks the grid up at n evenly spaced points of the segment between them,
 * which reads memory as coherently as a tracking loop does along its ray. */
#include "grid.h"

/* 32-bit integer hash (a PCG output permutation): cheap, so the ceiling is the lookups'. */
inline uint bench_hash(uint x) {
    uint s = x * 747796405u + 2891336453u;
    uint w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return (w >> 22u) ^ w;
}

inline float bench_uniform(uint *state) {
    *state = bench_hash(*state);
    return (float)(*state >> 8) * 0x1p-24f;
}

kernel void lookup_throughput(global const float *grid, int4 dims, float4 bmin4, float4 bmax4,
                              uint n_lookups, uint seed, global float *out) {
    uint gid = get_global_id(0);
    uint st = bench_hash(gid ^ bench_hash(seed));
    float3 bmin = bmin4.xyz, ext = bmax4.xyz - bmin4.xyz;
    float3 inv_extent = 1.0f / ext;
    float3 a = bmin + ext * (float3)(bench_uniform(&st), bench_uniform(&st), bench_uniform(&st));
    float3 b = bmin + ext * (float3)(bench_uniform(&st), bench_uniform(&st), bench_uniform(&st));
    float3 step = (b - a) / (float)n_lookups;
    float acc = 0.0f;
    for (uint k = 0; k < n_lookups; k++)
        acc += grid_lookup(grid, dims.xyz, bmin, inv_extent, a + ((float)k + 0.5f) * step);
    out[gid] = acc;
}
