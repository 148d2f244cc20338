/* Density grid lookups: trilinear between voxel centres, clamp-to-edge. Twin of
 * volmc/reference/grid.py (convention there). The grid is [z][y][x] float32, x fastest;
 * its shape travels as dims = (nx, ny, nz) since a C pointer carries none. One point per
 * lane: the index arithmetic is vector code, the eight fetches are gathers. A lane outside
 * `active` reads voxel 0 (its point may be anything), so no lane ever reads out of bounds. */
#ifndef VOLMC_GRID_H
#define VOLMC_GRID_H

#include "lanes.h"

/* Same operation order as the reference: a (1 - t) + b t. */
static inline lfloat lerp_ab(lfloat a, lfloat b, lfloat t) { return a * (1.0f - t) + b * t; }

/* The voxels trilinear interpolation at p blends: the lower corner i, the upper one j (each
 * clamped into the grid) and the weights f of the upper one, per axis. */
typedef struct {
    lint3 i, j;
    lvec3 f;
} VoxelCell;

/* One axis of voxel_cell: the continuous voxel coordinate clamped to [0, n - 1], whose
 * truncation is its floor (it is >= 0; far cheaper than floor() on PoCL). */
static inline lint voxel_axis(lfloat p, float bmin, float inv_extent, int n, lmask active,
                              lint *j, lfloat *f) {
    lfloat x = clamp((p - bmin) * inv_extent * (float)n - 0.5f, 0.0f, (float)(n - 1));
    lint i = select((lint)(0), min(to_lint_rtz(x), n - 1), active);
    *f = x - to_lfloat(i);
    *j = min(i + 1, n - 1);
    return i;
}

/* grid_lookup's and sparse_lookup's cell of p (a lane outside `active` gets voxel 0). */
static inline VoxelCell voxel_cell(int3 dims, float3 bmin, float3 inv_extent, lvec3 p,
                                   lmask active) {
    VoxelCell c;
    c.i.x = voxel_axis(p.x, bmin.x, inv_extent.x, dims.x, active, &c.j.x, &c.f.x);
    c.i.y = voxel_axis(p.y, bmin.y, inv_extent.y, dims.y, active, &c.j.y, &c.f.y);
    c.i.z = voxel_axis(p.z, bmin.z, inv_extent.z, dims.z, active, &c.j.z, &c.f.z);
    return c;
}

static inline lfloat grid_lookup(global const float *grid, int3 dims, float3 bmin,
                                 float3 inv_extent, lvec3 p, lmask active) {
    VoxelCell c = voxel_cell(dims, bmin, inv_extent, p, active);
    lint ix = c.i.x, iy = c.i.y, iz = c.i.z, jx = c.j.x, jy = c.j.y, jz = c.j.z;
    lfloat fx = c.f.x, fy = c.f.y, fz = c.f.z;
    /* int indices: grids are limited to 2^31 voxels (checked on upload). */
    int sy = dims.x, sz = dims.x * dims.y;
    lint r00 = iz * sz + iy * sy, r10 = iz * sz + jy * sy;
    lint r01 = jz * sz + iy * sy, r11 = jz * sz + jy * sy;
    lfloat c00 = lerp_ab(gather_float(grid, r00 + ix), gather_float(grid, r00 + jx), fx);
    lfloat c10 = lerp_ab(gather_float(grid, r10 + ix), gather_float(grid, r10 + jx), fx);
    lfloat c01 = lerp_ab(gather_float(grid, r01 + ix), gather_float(grid, r01 + jx), fx);
    lfloat c11 = lerp_ab(gather_float(grid, r11 + ix), gather_float(grid, r11 + jx), fx);
    return lerp_ab(lerp_ab(c00, c10, fy), lerp_ab(c01, c11, fy), fz);
}

/* Sparse brick grids: twin of sparse_lookup in volmc/reference/sparse_grid.py, whose docstring
 * specifies the storage. The logical grid is the dense grid above (dims, voxel centres,
 * trilinear, clamp-to-edge), cut into bricks of 8^3 voxels:
 *   table: int [bz][by][bx], bz = ceil(nz / 8) ..., the pool slot of each brick;
 *   pool:  float [n_slots][8][8][8] ([z][y][x], x fastest); slot 0 is the shared empty
 *          brick (all zeros) every all-zero brick points to.
 * Voxel (x, y, z) is pool[(slot << 9) | ((z & 7) << 6) | ((y & 7) << 3) | (x & 7)] with
 * slot = table[((z >> 3) * by + (y >> 3)) * bx + (x >> 3)]. The index and weight arithmetic
 * and the interpolation order are grid_lookup's, so the result is grid_lookup's on the dense
 * array bit for bit; only the eight fetches differ. The table is read for every corner, with
 * no branch: a one-brick fast path (one table read when the eight corners share a brick, as
 * the Numba twin does) measured 5-10 % slower on PoCL for random points and no faster along
 * rays (volmc/bench/sparse.py). Table indices are int (fewer than 2^31 bricks); pool offsets
 * are size_t, so the pool may exceed 2^31 voxels. */
static inline lfloat sparse_lookup(global const int *table, global const float *pool, int3 dims,
                                   float3 bmin, float3 inv_extent, lvec3 p, lmask active) {
    VoxelCell c = voxel_cell(dims, bmin, inv_extent, p, active);
    lint ix = c.i.x, iy = c.i.y, iz = c.i.z, jx = c.j.x, jy = c.j.y, jz = c.j.z;
    lfloat fx = c.f.x, fy = c.f.y, fz = c.f.z;
    int3 nb = (dims + 7) >> 3; /* bricks per axis */
    /* brick of the lower and upper corner, and voxel within its brick */
    lint bx0 = ix >> 3, by0 = iy >> 3, bz0 = iz >> 3, bx1 = jx >> 3, by1 = jy >> 3, bz1 = jz >> 3;
    lint ax0 = ix & 7, ay0 = iy & 7, az0 = iz & 7, ax1 = jx & 7, ay1 = jy & 7, az1 = jz & 7;
    /* table rows (brick z, y) and offsets within a brick (voxel z, y) */
    lint t00 = (bz0 * nb.y + by0) * nb.x, t10 = (bz0 * nb.y + by1) * nb.x;
    lint t01 = (bz1 * nb.y + by0) * nb.x, t11 = (bz1 * nb.y + by1) * nb.x;
    lint r00 = (az0 << 6) | (ay0 << 3), r10 = (az0 << 6) | (ay1 << 3);
    lint r01 = (az1 << 6) | (ay0 << 3), r11 = (az1 << 6) | (ay1 << 3);
    lfloat v000 = gather_float_brick(pool, gather_int(table, t00 + bx0), r00 | ax0);
    lfloat v001 = gather_float_brick(pool, gather_int(table, t00 + bx1), r00 | ax1);
    lfloat v010 = gather_float_brick(pool, gather_int(table, t10 + bx0), r10 | ax0);
    lfloat v011 = gather_float_brick(pool, gather_int(table, t10 + bx1), r10 | ax1);
    lfloat v100 = gather_float_brick(pool, gather_int(table, t01 + bx0), r01 | ax0);
    lfloat v101 = gather_float_brick(pool, gather_int(table, t01 + bx1), r01 | ax1);
    lfloat v110 = gather_float_brick(pool, gather_int(table, t11 + bx0), r11 | ax0);
    lfloat v111 = gather_float_brick(pool, gather_int(table, t11 + bx1), r11 | ax1);
    /* grid_lookup's order: c[zy] along x, then y, then z. */
    lfloat c00 = lerp_ab(v000, v001, fx), c10 = lerp_ab(v010, v011, fx);
    lfloat c01 = lerp_ab(v100, v101, fx), c11 = lerp_ab(v110, v111, fx);
    return lerp_ab(lerp_ab(c00, c10, fy), lerp_ab(c01, c11, fy), fz);
}

#endif
