/* Sparse-grid lookup speed for volmc/bench/sparse.py (twin of its Numba loops: same hash,
 * same points). Built with -DLOOKUP_KIND=0 (grid_lookup on the dense grid), 1
 * (sparse_lookup_fast_path below: one table read when the eight corners share a brick, as
 * the Numba sparse_lookup does; kept here only to measure it) or 2 (sparse_lookup of grid.h:
 * the table read for every corner, no branch).
 *
 * Work item i sums n_per_item lookups at points drawn by a 32-bit hash:
 *   mode 0: uniform in the box;
 *   mode 1: uniform in a random non-empty brick (bricks: (x, y, z) brick indices, n_bricks);
 *   mode 2: a ray from a random point of a random non-empty brick in a random direction,
 *           points half a voxel apart (coherent, as tracking reads). */
#include "grid.h"

static inline uint sb_hash(uint x) {
    uint s = x * 747796405u + 2891336453u;
    uint w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return (w >> 22u) ^ w;
}

static inline float sb_unit(uint *st) {
    *st = sb_hash(*st);
    return (float)(*st >> 8) * 0x1p-24f;
}

static inline float sparse_lookup_fast_path(global const int *table, global const float *pool,
                                            int3 dims, float3 bmin, float3 inv_extent, float3 p) {
    float3 x = (p - bmin) * inv_extent * convert_float3(dims) - 0.5f;
    x = clamp(x, (float3)(0.0f), convert_float3(dims - 1));
    int3 i0 = min(convert_int3_rtz(x), dims - 1);
    float3 f = x - convert_float3(i0);
    int3 i1 = min(i0 + 1, dims - 1);
    int3 nb = (dims + 7) >> 3;     /* bricks per axis */
    int3 b0 = i0 >> 3, b1 = i1 >> 3; /* brick of the lower and upper corner */
    int3 a0 = i0 & 7, a1 = i1 & 7;   /* voxel within its brick */
    /* offsets within a brick: rows (z, y) and columns x */
    int r00 = (a0.z << 6) | (a0.y << 3), r10 = (a0.z << 6) | (a1.y << 3);
    int r01 = (a1.z << 6) | (a0.y << 3), r11 = (a1.z << 6) | (a1.y << 3);
    float v000, v001, v010, v011, v100, v101, v110, v111;
    if (all(b0 == b1)) {
        global const float *b = pool + ((size_t)table[(b0.z * nb.y + b0.y) * nb.x + b0.x] << 9);
        v000 = b[r00 | a0.x]; v001 = b[r00 | a1.x];
        v010 = b[r10 | a0.x]; v011 = b[r10 | a1.x];
        v100 = b[r01 | a0.x]; v101 = b[r01 | a1.x];
        v110 = b[r11 | a0.x]; v111 = b[r11 | a1.x];
    } else {
        int t00 = (b0.z * nb.y + b0.y) * nb.x, t10 = (b0.z * nb.y + b1.y) * nb.x;
        int t01 = (b1.z * nb.y + b0.y) * nb.x, t11 = (b1.z * nb.y + b1.y) * nb.x;
        v000 = pool[((size_t)table[t00 + b0.x] << 9) | (r00 | a0.x)];
        v001 = pool[((size_t)table[t00 + b1.x] << 9) | (r00 | a1.x)];
        v010 = pool[((size_t)table[t10 + b0.x] << 9) | (r10 | a0.x)];
        v011 = pool[((size_t)table[t10 + b1.x] << 9) | (r10 | a1.x)];
        v100 = pool[((size_t)table[t01 + b0.x] << 9) | (r01 | a0.x)];
        v101 = pool[((size_t)table[t01 + b1.x] << 9) | (r01 | a1.x)];
        v110 = pool[((size_t)table[t11 + b0.x] << 9) | (r11 | a0.x)];
        v111 = pool[((size_t)table[t11 + b1.x] << 9) | (r11 | a1.x)];
    }
    /* grid_lookup's order: c[zy] along x, then y, then z. */
    float c00 = lerp_ab(v000, v001, f.x), c10 = lerp_ab(v010, v011, f.x);
    float c01 = lerp_ab(v100, v101, f.x), c11 = lerp_ab(v110, v111, f.x);
    return lerp_ab(lerp_ab(c00, c10, f.y), lerp_ab(c01, c11, f.y), f.z);
}

static inline float sb_lookup(global const float *grid, global const int *table,
                              global const float *pool, int3 dims, float3 bmin, float3 inv_extent,
                              float3 p) {
#if LOOKUP_KIND == 0
    return grid_lookup(grid, dims, bmin, inv_extent, p);
#elif LOOKUP_KIND == 1
    return sparse_lookup_fast_path(table, pool, dims, bmin, inv_extent, p);
#else
    return sparse_lookup(table, pool, dims, bmin, inv_extent, p);
#endif
}

/* A point in brick (x, y, z) = bricks[3 k ...] of a random k, as voxel coordinates. */
static inline float3 sb_brick_point(global const int *bricks, uint n_bricks, int3 dims, uint *st) {
    *st = sb_hash(*st);
    uint k = *st % n_bricks;
    float3 v = (float3)(bricks[3 * k], bricks[3 * k + 1], bricks[3 * k + 2]) * 8.0f;
    float ux = sb_unit(st), uy = sb_unit(st), uz = sb_unit(st); /* in this order */
    return fmin(v + (float3)(ux, uy, uz) * 8.0f, convert_float3(dims));
}

kernel void sparse_bench(global const float *grid, global const int *table,
                         global const float *pool, int4 dims4, float4 bmin4, float4 bmax4,
                         global const int *bricks, uint n_bricks, int mode, uint n_per_item,
                         uint seed, global float *out) {
    uint gid = get_global_id(0);
    int3 dims = dims4.xyz;
    float3 bmin = bmin4.xyz, ext = bmax4.xyz - bmin;
    float3 inv_extent = 1.0f / ext;
    float3 vox = ext / convert_float3(dims); /* world size of a voxel */
    uint st = sb_hash(gid ^ sb_hash(seed));
    float acc = 0.0f;
    if (mode == 2) {
        float3 o = bmin + sb_brick_point(bricks, n_bricks, dims, &st) * vox;
        float z = 2.0f * sb_unit(&st) - 1.0f;
        float phi = 6.2831853f * sb_unit(&st);
        float r = sqrt(fmax(0.0f, 1.0f - z * z));
        float3 step = (float3)(r * cos(phi), r * sin(phi), z) * 0.5f * vox;
        for (uint k = 0; k < n_per_item; k++)
            acc += sb_lookup(grid, table, pool, dims, bmin, inv_extent, o + (float)k * step);
    } else {
        for (uint k = 0; k < n_per_item; k++) {
            float3 p;
            if (mode == 0) {
                float ux = sb_unit(&st), uy = sb_unit(&st), uz = sb_unit(&st);
                p = bmin + (float3)(ux, uy, uz) * ext;
            } else
                p = bmin + sb_brick_point(bricks, n_bricks, dims, &st) * vox;
            acc += sb_lookup(grid, table, pool, dims, bmin, inv_extent, p);
        }
    }
    out[gid] = acc;
}
