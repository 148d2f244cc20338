"""Density grid lookups: trilinear between voxel centres, clamp-to-edge.

Convention (docs/scene_format.md; shared with ``kernels/grid.h``):

* ``grid`` is indexed [z, y, x] (C order, x fastest), shape (nz, ny, nx).
* Voxel (i, j, k) = (x, y, z) has its centre at bmin + ((i, j, k) + 0.5) / (nx, ny, nz) * extent.
* Between voxel centres the value is trilinear; within half a voxel of a face it is clamped to
  the edge voxels, so a constant grid is exactly a homogeneous medium. Points outside the box
  are never looked up (callers clip rays to the box first); coordinates are clamped anyway
  so a point rounding to just outside reads the edge value instead of out-of-bounds memory.
"""

from numba import njit


@njit(cache=True, inline="always")
def _axis(p, bmin, inv_extent, n):
    """Lower voxel index and weight of the upper neighbour along one axis."""
    x = (p - bmin) * inv_extent * n - 0.5
    x = min(max(x, 0.0), n - 1.0)
    i0 = min(int(x), n - 1)  # x >= 0 after the clamp: truncation is floor
    f = x - i0
    i1 = min(i0 + 1, n - 1)
    return i0, i1, f


@njit(cache=True, inline="always")
def grid_lookup(grid, bmin, inv_extent, p):
    """Trilinearly interpolated density at world point p (no scale applied).

    grid: float array [nz, ny, nx]; bmin: box minimum (3-tuple, world units);
    inv_extent: 1 / (bmax - bmin) per axis (3-tuple, 1/world unit); p: 3-tuple.
    """
    nz, ny, nx = grid.shape
    x0, x1, fx = _axis(p[0], bmin[0], inv_extent[0], nx)
    y0, y1, fy = _axis(p[1], bmin[1], inv_extent[1], ny)
    z0, z1, fz = _axis(p[2], bmin[2], inv_extent[2], nz)
    c00 = grid[z0, y0, x0] * (1.0 - fx) + grid[z0, y0, x1] * fx
    c10 = grid[z0, y1, x0] * (1.0 - fx) + grid[z0, y1, x1] * fx
    c01 = grid[z1, y0, x0] * (1.0 - fx) + grid[z1, y0, x1] * fx
    c11 = grid[z1, y1, x0] * (1.0 - fx) + grid[z1, y1, x1] * fx
    c0 = c00 * (1.0 - fy) + c10 * fy
    c1 = c01 * (1.0 - fy) + c11 * fy
    return c0 * (1.0 - fz) + c1 * fz
