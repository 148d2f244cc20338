"""Majorant grids: coarse per-cell bounds of a trilinear density grid.

The box is split into (cx, cy, cz) equal cells. Inside a cell, the clamp-to-edge trilinear
density at any point is a convex combination of the voxels whose centres bracket that point,
so the maximum (minimum) over every voxel that can influence the cell bounds the density
from above (below) everywhere in the cell, including at its faces. Along one axis, a cell
covering voxel coordinates x in [xa, xb] (x = position / voxel size - 0.5, clamped to
[0, n - 1]) is influenced by voxels floor(xa) ... min(floor(xb) + 1, n - 1).

Arrays are indexed [z, y, x] like the density grid; bounds are of the density (multiply by
the medium's scale for extinction).
"""

import math

import numpy as np

#: Voxels per majorant cell along an axis when the resolution is chosen automatically.
VOXELS_PER_CELL = 8
#: Cells per axis at most (automatic choice).
MAX_CELLS = 64


def auto_resolution(shape_zyx):
    """Cells per axis (cz, cy, cx): about VOXELS_PER_CELL voxels per cell, 1 to MAX_CELLS."""
    return tuple(int(min(MAX_CELLS, max(1, math.ceil(n / VOXELS_PER_CELL)))) for n in shape_zyx)


def influence_ranges(n_voxels, n_cells):
    """For each of n_cells equal cells along an axis of n_voxels voxels: the first and last
    voxel index (inclusive) that trilinear interpolation can read inside the cell."""
    edges = np.arange(n_cells + 1) * (n_voxels / n_cells) - 0.5   # voxel coordinates
    x = np.clip(edges, 0.0, n_voxels - 1)
    lo = np.floor(x[:-1]).astype(np.int64)
    hi = np.minimum(np.floor(x[1:]).astype(np.int64) + 1, n_voxels - 1)
    return lo, hi


def build_majorant_grid(grid, resolution=None, minima=True):
    """(maxima, minima) float32 arrays [cz, cy, cx] bounding ``grid`` in every cell.

    resolution: (cz, cy, cx) cells, or None for ``auto_resolution(grid.shape)``.
    minima: False skips the minima (None in their place)."""
    grid = np.asarray(grid)
    res = auto_resolution(grid.shape) if resolution is None else tuple(int(r) for r in resolution)
    if len(res) != 3 or min(res) < 1:
        raise ValueError(f"majorant resolution must be 3 positive integers, got {resolution}")
    rz, ry, rx = (influence_ranges(n, c) for n, c in zip(grid.shape, res))
    # Reduce one axis at a time: a max over a box is the max over its axis-aligned pieces.
    def reduce(a, ranges, axis, fn):
        lo, hi = ranges
        parts = [fn(np.take(a, np.arange(l, h + 1), axis=axis), axis=axis, keepdims=True)
                 for l, h in zip(lo, hi)]
        return np.concatenate(parts, axis=axis)
    out = []
    for fn in (np.max, np.min) if minima else (np.max,):
        a = reduce(grid, rx, 2, fn)
        a = reduce(a, ry, 1, fn)
        a = reduce(a, rz, 0, fn)
        out.append(np.ascontiguousarray(a, dtype=np.float32))
    return out[0], (out[1] if minima else None)


def cell_of(p, bmin, bmax, res_zyx):
    """Cell index (iz, iy, ix) of world points p [n, 3] (x, y, z), clamped into the grid."""
    p = np.asarray(p, np.float64)
    frac = (p - np.asarray(bmin)) / (np.asarray(bmax) - np.asarray(bmin))
    cx, cy, cz = res_zyx[2], res_zyx[1], res_zyx[0]
    ix = np.clip((frac[:, 0] * cx).astype(np.int64), 0, cx - 1)
    iy = np.clip((frac[:, 1] * cy).astype(np.int64), 0, cy - 1)
    iz = np.clip((frac[:, 2] * cz).astype(np.int64), 0, cz - 1)
    return iz, iy, ix
