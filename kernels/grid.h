/* Density grid lookups: trilinear between voxel centres, clamp-to-edge. Twin of
 * volmc/reference/grid.py (convention there). The grid is [z][y][x] float32, x fastest;
 * its shape travels as dims = (nx, ny, nz) since a C pointer carries none. */
#ifndef VOLMC_GRID_H
#define VOLMC_GRID_H

inline void grid_axis(float p, float bmin, float inv_extent, int n, int *i0, int *i1, float *f) {
    float x = (p - bmin) * inv_extent * (float)n - 0.5f;
    x = clamp(x, 0.0f, (float)(n - 1));
    int i = min((int)floor(x), n - 1);
    *i0 = i;
    *f = x - (float)i;
    *i1 = min(i + 1, n - 1);
}

/* Same operation order as the reference: a (1 - t) + b t. */
inline float lerp_ab(float a, float b, float t) { return a * (1.0f - t) + b * t; }

inline float grid_lookup(global const float *grid, int3 dims, float3 bmin, float3 inv_extent,
                         float3 p) {
    int x0, x1, y0, y1, z0, z1;
    float fx, fy, fz;
    grid_axis(p.x, bmin.x, inv_extent.x, dims.x, &x0, &x1, &fx);
    grid_axis(p.y, bmin.y, inv_extent.y, dims.y, &y0, &y1, &fy);
    grid_axis(p.z, bmin.z, inv_extent.z, dims.z, &z0, &z1, &fz);
    size_t sy = (size_t)dims.x, sz = (size_t)dims.x * (size_t)dims.y;
    size_t r00 = z0 * sz + y0 * sy, r10 = z0 * sz + y1 * sy;
    size_t r01 = z1 * sz + y0 * sy, r11 = z1 * sz + y1 * sy;
    float c00 = lerp_ab(grid[r00 + x0], grid[r00 + x1], fx);
    float c10 = lerp_ab(grid[r10 + x0], grid[r10 + x1], fx);
    float c01 = lerp_ab(grid[r01 + x0], grid[r01 + x1], fx);
    float c11 = lerp_ab(grid[r11 + x0], grid[r11 + x1], fx);
    float c0 = lerp_ab(c00, c10, fy);
    float c1 = lerp_ab(c01, c11, fy);
    return lerp_ab(c0, c1, fz);
}

#endif
