/* Density grid lookups: trilinear between voxel centres, clamp-to-edge. Twin of
 * volmc/reference/grid.py (convention there). The grid is [z][y][x] float32, x fastest;
 * its shape travels as dims = (nx, ny, nz) since a C pointer carries none. */
#ifndef VOLMC_GRID_H
#define VOLMC_GRID_H

/* Same operation order as the reference: a (1 - t) + b t. */
inline float lerp_ab(float a, float b, float t) { return a * (1.0f - t) + b * t; }

inline float grid_lookup(global const float *grid, int3 dims, float3 bmin, float3 inv_extent,
                         float3 p) {
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

#endif
