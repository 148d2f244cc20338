/* Sparse-grid lookup speed for volmc/bench/sparse.py (twin of its Numba loops: same hash,
 * same points). Built with -DLOOKUP_KIND=0 (grid_lookup on the dense grid), 1
 * (sparse_lookup_fast_path below: one table read when the eight corners share a brick, as
 * the Numba sparse_lookup does; kept here only to measure it) or 2 (sparse_lookup of grid.h:
 * the table read for every corner, no branch).
 *
 * Lane l of work-item i is item i W + l: it sums n_per_item lookups at points drawn by a
 * 32-bit hash:
 *   mode 0: uniform in the box;
 *   mode 1: uniform in a random non-empty brick (bricks: (x, y, z) brick indices, n_bricks);
 *   mode 2: a ray from a random point of a random non-empty brick in a random direction,
 *           points half a voxel apart (coherent, as tracking reads). */
#include "lanes.h"
#include "lane_io.h"
#include "grid.h"

static inline luint sb_hash(luint x) {
    luint s = x * 747796405u + 2891336453u;
    luint w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return (w >> 22u) ^ w;
}

static inline lfloat sb_unit(luint *st) {
    *st = sb_hash(*st);
    return to_lfloat(*st >> 8) * 0x1p-24f;
}

/* The one-brick fast path: a branch, so in lanes it pays only when every lane's corners share
 * a brick (one table read per lane); otherwise every lane reads a table entry per corner. */
static inline lfloat sparse_lookup_fast_path(global const int *table, global const float *pool,
                                             int3 dims, float3 bmin, float3 inv_extent, lvec3 p,
                                             lmask active) {
    VoxelCell c = voxel_cell(dims, bmin, inv_extent, p, active);
    lint ix = c.i.x, iy = c.i.y, iz = c.i.z, jx = c.j.x, jy = c.j.y, jz = c.j.z;
    lfloat fx = c.f.x, fy = c.f.y, fz = c.f.z;
    lmask one = (ix >> 3 == jx >> 3) & (iy >> 3 == jy >> 3) & (iz >> 3 == jz >> 3);
    if (!ALL(one | !active))
        return sparse_lookup(table, pool, dims, bmin, inv_extent, p, active);
    int3 nb = (dims + 7) >> 3;
    lint slot = gather_int(table, ((iz >> 3) * nb.y + (iy >> 3)) * nb.x + (ix >> 3));
    lint ax0 = ix & 7, ay0 = iy & 7, az0 = iz & 7, ax1 = jx & 7, ay1 = jy & 7, az1 = jz & 7;
    lint r00 = (az0 << 6) | (ay0 << 3), r10 = (az0 << 6) | (ay1 << 3);
    lint r01 = (az1 << 6) | (ay0 << 3), r11 = (az1 << 6) | (ay1 << 3);
    lfloat c00 = lerp_ab(gather_float_brick(pool, slot, r00 | ax0),
                         gather_float_brick(pool, slot, r00 | ax1), fx);
    lfloat c10 = lerp_ab(gather_float_brick(pool, slot, r10 | ax0),
                         gather_float_brick(pool, slot, r10 | ax1), fx);
    lfloat c01 = lerp_ab(gather_float_brick(pool, slot, r01 | ax0),
                         gather_float_brick(pool, slot, r01 | ax1), fx);
    lfloat c11 = lerp_ab(gather_float_brick(pool, slot, r11 | ax0),
                         gather_float_brick(pool, slot, r11 | ax1), fx);
    return lerp_ab(lerp_ab(c00, c10, fy), lerp_ab(c01, c11, fy), fz);
}

static inline lfloat sb_lookup(global const float *grid, global const int *table,
                               global const float *pool, int3 dims, float3 bmin,
                               float3 inv_extent, lvec3 p, lmask active) {
#if LOOKUP_KIND == 0
    return grid_lookup(grid, dims, bmin, inv_extent, p, active);
#elif LOOKUP_KIND == 1
    return sparse_lookup_fast_path(table, pool, dims, bmin, inv_extent, p, active);
#else
    return sparse_lookup(table, pool, dims, bmin, inv_extent, p, active);
#endif
}

/* A point in brick (x, y, z) = bricks[3 k ...] of a random k, as voxel coordinates. */
static inline lvec3 sb_brick_point(global const int *bricks, uint n_bricks, int3 dims,
                                   luint *st) {
    *st = sb_hash(*st);
    lint k = as_lint(*st % n_bricks);
    lvec3 v = scale3(v3(to_lfloat(gather_int(bricks, 3 * k)), to_lfloat(gather_int(bricks, 3 * k + 1)),
                        to_lfloat(gather_int(bricks, 3 * k + 2))),
                     (lfloat)(8.0f));
    lfloat ux = sb_unit(st), uy = sb_unit(st), uz = sb_unit(st); /* in this order */
    return v3(fmin(v.x + ux * 8.0f, (float)dims.x), fmin(v.y + uy * 8.0f, (float)dims.y),
              fmin(v.z + uz * 8.0f, (float)dims.z));
}

kernel void sparse_bench(global const float *grid, global const int *table,
                         global const float *pool, int4 dims4, float4 bmin4, float4 bmax4,
                         global const int *bricks, uint n_bricks, int mode, uint n_per_item,
                         uint seed, global float *out, int n) {
    lmask on;
    lint gid = lane_element(n, &on);
    int3 dims = dims4.xyz;
    float3 bmin = bmin4.xyz, ext = bmax4.xyz - bmin;
    float3 inv_extent = 1.0f / ext;
    float3 vox = ext / convert_float3(dims); /* world size of a voxel */
    luint st = sb_hash(as_luint(gid) ^ sb_hash((luint)(seed)));
    lfloat acc = (lfloat)(0.0f);
    if (mode == 2) {
        lvec3 o = add3(v3u(bmin), mul3(sb_brick_point(bricks, n_bricks, dims, &st), v3u(vox)));
        lfloat z = 2.0f * sb_unit(&st) - 1.0f;
        lfloat phi = 6.2831853f * sb_unit(&st);
        lfloat r = sqrt(fmax(0.0f, 1.0f - z * z));
        lvec3 step = mul3(scale3(v3(r * cos(phi), r * sin(phi), z), (lfloat)(0.5f)), v3u(vox));
        for (uint k = 0; k < n_per_item; k++)
            acc += sb_lookup(grid, table, pool, dims, bmin, inv_extent,
                             madd3(o, step, (lfloat)((float)k)), on);
    } else {
        for (uint k = 0; k < n_per_item; k++) {
            lvec3 p;
            if (mode == 0) {
                lfloat ux = sb_unit(&st), uy = sb_unit(&st), uz = sb_unit(&st);
                p = add3(v3u(bmin), mul3(v3(ux, uy, uz), v3u(ext)));
            } else
                p = add3(v3u(bmin), mul3(sb_brick_point(bricks, n_bricks, dims, &st), v3u(vox)));
            acc += sb_lookup(grid, table, pool, dims, bmin, inv_extent, p, on);
        }
    }
    store_float(out, gid, 1, 0, acc, on);
}
