/* Density grid lookups: trilinear between voxel centres, clamp-to-edge. Twin of
 * volmc/reference/grid.py (convention there). The grid is [z][y][x] float32, x fastest;
 * its shape travels as dims = (nx, ny, nz) since a C pointer carries none. */
#ifndef VOLMC_GRID_H
#define VOLMC_GRID_H

/* Same operation order as the reference: a (1 - t) + b t. */
static inline float lerp_ab(float a, float b, float t) { return a * (1.0f - t) + b * t; }

static inline float grid_lookup(global const float *grid, int3 dims, float3 bmin,
                                float3 inv_extent, float3 p) {
    float3 x = (p - bmin) * inv_extent * convert_float3(dims) - 0.5f;
    x = clamp(x, (float3)(0.0f), convert_float3(dims - 1));
    /* x >= 0 after the clamp, so truncation is floor (and far cheaper than floor() on PoCL). */
    int3 i0 = min(convert_int3_rtz(x), dims - 1);
    float3 f = x - convert_float3(i0);
    int3 i1 = min(i0 + 1, dims - 1);
    /* int indices: grids are limited to 2^31 voxels (checked on upload). */
    int sy = dims.x, sz = dims.x * dims.y;
    int r00 = i0.z * sz + i0.y * sy, r10 = i0.z * sz + i1.y * sy;
    int r01 = i1.z * sz + i0.y * sy, r11 = i1.z * sz + i1.y * sy;
    float c00 = lerp_ab(grid[r00 + i0.x], grid[r00 + i1.x], f.x);
    float c10 = lerp_ab(grid[r10 + i0.x], grid[r10 + i1.x], f.x);
    float c01 = lerp_ab(grid[r01 + i0.x], grid[r01 + i1.x], f.x);
    float c11 = lerp_ab(grid[r11 + i0.x], grid[r11 + i1.x], f.x);
    return lerp_ab(lerp_ab(c00, c10, f.y), lerp_ab(c01, c11, f.y), f.z);
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
static inline float sparse_lookup(global const int *table, global const float *pool, int3 dims,
                                  float3 bmin, float3 inv_extent, float3 p) {
    float3 x = (p - bmin) * inv_extent * convert_float3(dims) - 0.5f;
    x = clamp(x, (float3)(0.0f), convert_float3(dims - 1));
    int3 i0 = min(convert_int3_rtz(x), dims - 1);
    float3 f = x - convert_float3(i0);
    int3 i1 = min(i0 + 1, dims - 1);
    int3 nb = (dims + 7) >> 3;       /* bricks per axis */
    int3 b0 = i0 >> 3, b1 = i1 >> 3; /* brick of the lower and upper corner */
    int3 a0 = i0 & 7, a1 = i1 & 7;   /* voxel within its brick */
    /* table rows (brick z, y) and offsets within a brick (voxel z, y) */
    int t00 = (b0.z * nb.y + b0.y) * nb.x, t10 = (b0.z * nb.y + b1.y) * nb.x;
    int t01 = (b1.z * nb.y + b0.y) * nb.x, t11 = (b1.z * nb.y + b1.y) * nb.x;
    int r00 = (a0.z << 6) | (a0.y << 3), r10 = (a0.z << 6) | (a1.y << 3);
    int r01 = (a1.z << 6) | (a0.y << 3), r11 = (a1.z << 6) | (a1.y << 3);
    float v000 = pool[((size_t)table[t00 + b0.x] << 9) | (r00 | a0.x)];
    float v001 = pool[((size_t)table[t00 + b1.x] << 9) | (r00 | a1.x)];
    float v010 = pool[((size_t)table[t10 + b0.x] << 9) | (r10 | a0.x)];
    float v011 = pool[((size_t)table[t10 + b1.x] << 9) | (r10 | a1.x)];
    float v100 = pool[((size_t)table[t01 + b0.x] << 9) | (r01 | a0.x)];
    float v101 = pool[((size_t)table[t01 + b1.x] << 9) | (r01 | a1.x)];
    float v110 = pool[((size_t)table[t11 + b0.x] << 9) | (r11 | a0.x)];
    float v111 = pool[((size_t)table[t11 + b1.x] << 9) | (r11 | a1.x)];
    /* grid_lookup's order: c[zy] along x, then y, then z. */
    float c00 = lerp_ab(v000, v001, f.x), c10 = lerp_ab(v010, v011, f.x);
    float c01 = lerp_ab(v100, v101, f.x), c11 = lerp_ab(v110, v111, f.x);
    return lerp_ab(lerp_ab(c00, c10, f.y), lerp_ab(c01, c11, f.y), f.z);
}

#endif
