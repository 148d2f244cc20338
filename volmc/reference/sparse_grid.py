"""Sparse brick grids: a density grid whose memory scales with its non-zero voxels.

Twin of the ``sparse_lookup`` in ``kernels/grid.h``. The builders and the majorant are host
code (numpy and Numba); they never allocate the dense array.

Storage
-------
The logical grid is the dense grid of grid.py: dims (nx, ny, nz) voxels, indexed [z, y, x],
voxel centres at bmin + ((i, j, k) + 0.5) / (nx, ny, nz) * extent, trilinear between centres
and clamp-to-edge. It is cut into bricks of 8 x 8 x 8 voxels, brick (bx, by, bz) holding the
voxels (8 bx .. 8 bx + 7, ...); there are (ceil(nx / 8), ceil(ny / 8), ceil(nz / 8)) bricks.

* ``table``: int32 [bz, by, bx] (C order, x fastest): the pool slot of each brick.
* ``pool``: float32 (kernels) or float64 (reference) [n_slots, 8, 8, 8], each slot a brick
  indexed [z][y][x] (x fastest), so voxel (x, y, z) is
  ``pool[table[z >> 3, y >> 3, x >> 3], z & 7, y & 7, x & 7]``, flat
  ``pool[(slot << 9) | ((z & 7) << 6) | ((y & 7) << 3) | (x & 7)]``.
* Slot 0 is the shared empty brick, all zeros: every all-zero brick points to it (a brick is
  all-zero when every voxel compares equal to 0, so -0.0 counts as zero). The other slots
  hold the non-empty bricks in raster order of their brick index (z, then y, then x), so
  the builders are deterministic and ``bricks_from_blocks`` and ``bricks_from_dense`` give
  identical arrays for the same logical grid.
* Bricks at the high faces may stick out of the grid when a dimension is not a multiple of
  8: their voxels beyond dims are stored as 0 and never read (lookups clamp indices into
  dims; the majorant ignores them).

Memory: 4 bytes per brick for the table (1/512 of a dense float32 grid) plus 2 KiB
(float32) per non-empty brick and one for the empty brick. Limits: the table holds fewer
than 2^31 bricks (int indices in the kernel) and the pool fewer than 2^31 - 1 slots; pool
offsets are computed in 64 bits, so the pool may exceed 2^31 voxels.

Lookup
------
``sparse_lookup(table, pool, dims, bmin, inv_extent, p)`` returns exactly what
``grid_lookup(dense, bmin, inv_extent, p)`` returns on the dense array (bit for bit: the
same index and weight arithmetic, ``_axis`` of grid.py, and the same interpolation order;
only the eight corner fetches go through the table). When the eight corners lie in one
brick (about (7/8)^3 of spread-out points) this twin reads the table once, otherwise once
per corner; the kernel reads it once per corner with no branch. Each is the faster way on
its backend (volmc/bench/sparse.py: the fast path gains 10-20 % in Numba and loses 5-10 %
on PoCL for random points); the results are the same either way.

Majorant
--------
``majorant_from_bricks`` gives exactly ``build_majorant_grid(dense, resolution)``
(majorant.py) without the dense array; the default resolution is the brick grid
(bz, by, bx). build_majorant_grid cuts the box into equal cells, which is what the DDA walks.
When every dim is a multiple of 8 those cells are exactly the bricks, and cell (kz, ky, kx)
is bounded by the voxels 8k - 1 .. 8k + 8 along each axis (the brick and a one-voxel layer
of its neighbours, clamped at the grid's edge). When a dim is not a multiple of 8 the cells
of that axis are n / ceil(n / 8) < 8 voxels wide and do not line up with the bricks; the
bounds are still exact for those cells (each is the extreme over that cell's own influence
range), so the DDA needs no change, but a cell is no longer one brick. (Cells that are the
bricks for any dims would need the DDA to walk a box padded to 8 ceil(n / 8) voxels, i.e. a
majorant box apart from the medium box in the Medium record; the lookup does not need the
cells to be bricks, so this module does not do that.) Any other resolution works too: with
n / c a multiple of 8 the cells are unions of bricks. The scene schema caps
render.majorant_resolution at 256 cells per axis and the automatic choice at 64, so cells
are bricks only up to 2048 (explicit) or 512 (automatic) voxels per axis.
"""

import math

import numpy as np
from numba import njit

from .grid import _axis
from .majorant import influence_ranges

#: Voxels per brick along an axis (a storage-format constant: kernels/grid.h uses the shifts
#: 3, 6 and 9 and the mask 7 that follow from it).
BRICK = 8


@njit(cache=True)
def sparse_lookup(table, pool, dims, bmin, inv_extent, p):
    """Trilinearly interpolated density at world point p in a brick grid (no scale applied):
    the value grid_lookup gives on the dense grid, bit for bit.

    table: int32 [bz, by, bx]; pool: float [n_slots, 8, 8, 8]; dims: (nx, ny, nz);
    bmin, inv_extent, p: 3-tuples as in grid_lookup."""
    x0, x1, fx = _axis(p[0], bmin[0], inv_extent[0], dims[0])
    y0, y1, fy = _axis(p[1], bmin[1], inv_extent[1], dims[1])
    z0, z1, fz = _axis(p[2], bmin[2], inv_extent[2], dims[2])
    ax0, ay0, az0 = x0 & 7, y0 & 7, z0 & 7
    ax1, ay1, az1 = x1 & 7, y1 & 7, z1 & 7
    if (x0 >> 3) == (x1 >> 3) and (y0 >> 3) == (y1 >> 3) and (z0 >> 3) == (z1 >> 3):
        b = pool[table[z0 >> 3, y0 >> 3, x0 >> 3]]
        v000, v001 = b[az0, ay0, ax0], b[az0, ay0, ax1]
        v010, v011 = b[az0, ay1, ax0], b[az0, ay1, ax1]
        v100, v101 = b[az1, ay0, ax0], b[az1, ay0, ax1]
        v110, v111 = b[az1, ay1, ax0], b[az1, ay1, ax1]
    else:
        v000 = pool[table[z0 >> 3, y0 >> 3, x0 >> 3], az0, ay0, ax0]
        v001 = pool[table[z0 >> 3, y0 >> 3, x1 >> 3], az0, ay0, ax1]
        v010 = pool[table[z0 >> 3, y1 >> 3, x0 >> 3], az0, ay1, ax0]
        v011 = pool[table[z0 >> 3, y1 >> 3, x1 >> 3], az0, ay1, ax1]
        v100 = pool[table[z1 >> 3, y0 >> 3, x0 >> 3], az1, ay0, ax0]
        v101 = pool[table[z1 >> 3, y0 >> 3, x1 >> 3], az1, ay0, ax1]
        v110 = pool[table[z1 >> 3, y1 >> 3, x0 >> 3], az1, ay1, ax0]
        v111 = pool[table[z1 >> 3, y1 >> 3, x1 >> 3], az1, ay1, ax1]
    # grid_lookup's order: c[zy] along x, then y, then z.
    c00 = v000 * (1.0 - fx) + v001 * fx
    c10 = v010 * (1.0 - fx) + v011 * fx
    c01 = v100 * (1.0 - fx) + v101 * fx
    c11 = v110 * (1.0 - fx) + v111 * fx
    c0 = c00 * (1.0 - fy) + c10 * fy
    c1 = c01 * (1.0 - fy) + c11 * fy
    return c0 * (1.0 - fz) + c1 * fz


# --- Host side: builders -------------------------------------------------------------------

def brick_shape(dims):
    """(bz, by, bx): bricks per axis of a grid of dims (nx, ny, nz)."""
    nx, ny, nz = _dims(dims)
    return (-(-nz // BRICK), -(-ny // BRICK), -(-nx // BRICK))


def _dims(dims):
    d = tuple(int(v) for v in dims)
    if len(d) != 3 or min(d) < 1:
        raise ValueError(f"dims must be 3 positive integers (nx, ny, nz), got {dims}")
    return d


def _new_table(dims):
    shape = brick_shape(dims)
    if math.prod(shape) >= 2**31:
        raise ValueError(f"{math.prod(shape)} bricks: the kernels index the table with an int")
    return np.zeros(shape, np.int32)


def _number_slots(table):
    """Turn an occupancy mark (non-zero = non-empty) into slots 1..m in raster order."""
    ids = np.flatnonzero(table)
    if len(ids) >= 2**31 - 1:
        raise ValueError(f"{len(ids)} non-empty bricks: slots are int32")
    flat = table.reshape(-1)
    flat[:] = 0
    flat[ids] = np.arange(1, len(ids) + 1, dtype=np.int32)
    return len(ids) + 1


@njit(cache=True)
def _mark_dense(grid, table):
    nz, ny, nx = grid.shape
    for z in range(nz):
        for y in range(ny):
            for x in range(nx):
                if grid[z, y, x] != 0:
                    table[z >> 3, y >> 3, x >> 3] = 1


@njit(cache=True)
def _fill_dense(grid, table, pool):
    nz, ny, nx = grid.shape
    bz, by, bx = table.shape
    for kz in range(bz):
        for ky in range(by):
            for kx in range(bx):
                s = table[kz, ky, kx]
                if s == 0:
                    continue
                for z in range(8 * kz, min(8 * kz + 8, nz)):
                    for y in range(8 * ky, min(8 * ky + 8, ny)):
                        for x in range(8 * kx, min(8 * kx + 8, nx)):
                            pool[s, z & 7, y & 7, x & 7] = grid[z, y, x]


def bricks_from_dense(grid, dtype=np.float32):
    """(table, pool) of a dense grid [nz, ny, nx]; pool in ``dtype``."""
    grid = np.ascontiguousarray(grid)
    if grid.ndim != 3 or grid.size == 0:
        raise ValueError(f"grid must be 3-D and non-empty, got shape {grid.shape}")
    nz, ny, nx = grid.shape
    table = _new_table((nx, ny, nz))
    _mark_dense(grid, table)
    n_slots = _number_slots(table)
    pool = np.zeros((n_slots, BRICK, BRICK, BRICK), dtype)
    _fill_dense(grid, table, pool)
    return table, pool


@njit(cache=True)
def _scatter_blocks(origins, values, nx, ny, nz, table, pool, fill):
    """Visit every voxel of the blocks that lies inside the grid: without ``fill``, mark the
    bricks holding a non-zero one in ``table``; with it, copy the voxels into the pool slots
    ``table`` has numbered (empty bricks, slot 0, are skipped)."""
    for b in range(origins.shape[0]):
        ox, oy, oz = origins[b, 0], origins[b, 1], origins[b, 2]
        for z in range(8):
            gz = oz + z
            if gz < 0 or gz >= nz:
                continue
            for y in range(8):
                gy = oy + y
                if gy < 0 or gy >= ny:
                    continue
                for x in range(8):
                    gx = ox + x
                    if gx < 0 or gx >= nx:
                        continue
                    if not fill:
                        if values[b, z, y, x] != 0:
                            table[gz >> 3, gy >> 3, gx >> 3] = 1
                        continue
                    s = table[gz >> 3, gy >> 3, gx >> 3]
                    if s != 0:
                        pool[s, gz & 7, gy & 7, gx & 7] = values[b, z, y, x]


def bricks_from_blocks(dims, origins, values, dtype=np.float32):
    """(table, pool) of a grid of dims (nx, ny, nz) given as 8^3 blocks, without building
    the dense array.

    origins: int [n, 3], the (x, y, z) voxel index of each block's minimum corner relative
    to the grid; any integers (OpenVDB leaf origins minus the bounding box's minimum are
    congruent to -bbox_min mod 8, so blocks straddle up to 8 bricks; they are scattered
    voxel by voxel). values: [n, 8, 8, 8] indexed [z][y][x]. Voxels outside dims are
    dropped; voxels no block covers are 0. Blocks should not overlap (OpenVDB leaves do
    not); where they do, later blocks win voxel by voxel, and a brick whose non-zero values
    were all overwritten by zeros keeps a slot of its own (lookups are unaffected)."""
    nx, ny, nz = _dims(dims)
    origins = np.ascontiguousarray(origins, np.int64).reshape(-1, 3)
    values = np.ascontiguousarray(values)
    if values.shape != (len(origins), BRICK, BRICK, BRICK):
        raise ValueError(f"values must be [{len(origins)}, 8, 8, 8], got {values.shape}")
    table = _new_table((nx, ny, nz))
    pool = np.zeros((1, BRICK, BRICK, BRICK), dtype)   # unused while marking
    _scatter_blocks(origins, values, nx, ny, nz, table, pool, False)
    n_slots = _number_slots(table)
    pool = np.zeros((n_slots, BRICK, BRICK, BRICK), dtype)
    _scatter_blocks(origins, values, nx, ny, nz, table, pool, True)
    return table, pool


def sparse_to_dense(table, pool, dims):
    """The dense grid [nz, ny, nx] of a brick grid (for tests and small grids)."""
    nx, ny, nz = _dims(dims)
    bz, by, bx = table.shape
    full = pool[table]                                    # [bz, by, bx, 8, 8, 8]
    full = full.transpose(0, 3, 1, 4, 2, 5).reshape(bz * BRICK, by * BRICK, bx * BRICK)
    return np.ascontiguousarray(full[:nz, :ny, :nx])


def sparse_nbytes(table, pool):
    """Bytes of a brick grid's two arrays."""
    return table.nbytes + pool.nbytes


# --- Host side: majorant grid --------------------------------------------------------------

@njit(cache=True)
def _slot_extrema(table, pool, nx, ny, nz, smax, smin):
    """Extremes of each slot over its voxels inside dims (slot 0: 0)."""
    bz, by, bx = table.shape
    for kz in range(bz):
        for ky in range(by):
            for kx in range(bx):
                s = table[kz, ky, kx]
                if s == 0:
                    continue
                hi = -np.inf
                lo = np.inf
                for z in range(min(8, nz - 8 * kz)):
                    for y in range(min(8, ny - 8 * ky)):
                        for x in range(min(8, nx - 8 * kx)):
                            v = pool[s, z, y, x]
                            hi = max(hi, v)
                            lo = min(lo, v)
                smax[s] = hi
                smin[s] = lo


@njit(cache=True)
def _mark_cells(table, cz_range, cy_range, cx_range, mark):
    """Mark every cell whose influence box meets a non-empty brick."""
    bz, by, bx = table.shape
    for kz in range(bz):
        for ky in range(by):
            for kx in range(bx):
                if table[kz, ky, kx] == 0:
                    continue
                for cz in range(cz_range[kz, 0], cz_range[kz, 1] + 1):
                    for cy in range(cy_range[ky, 0], cy_range[ky, 1] + 1):
                        for cx in range(cx_range[kx, 0], cx_range[kx, 1] + 1):
                            mark[cz, cy, cx] = 1


@njit(cache=True)
def _cell_extrema(table, pool, nx, ny, nz, rz, ry, rx, smax, smin, mark, mx, mn):
    """Extremes over each marked cell's influence box [lo, hi] (inclusive voxel ranges rz,
    ry, rx per cell), read brick by brick through the table; unmarked cells stay 0."""
    cz_n, cy_n, cx_n = mark.shape
    for cz in range(cz_n):
        z0, z1 = rz[cz, 0], rz[cz, 1]
        for cy in range(cy_n):
            y0, y1 = ry[cy, 0], ry[cy, 1]
            for cx in range(cx_n):
                if mark[cz, cy, cx] == 0:
                    continue
                x0, x1 = rx[cx, 0], rx[cx, 1]
                hi = -np.inf
                lo = np.inf
                for kz in range(z0 >> 3, (z1 >> 3) + 1):
                    za, zb = max(z0, 8 * kz), min(z1, 8 * kz + 7)
                    for ky in range(y0 >> 3, (y1 >> 3) + 1):
                        ya, yb = max(y0, 8 * ky), min(y1, 8 * ky + 7)
                        for kx in range(x0 >> 3, (x1 >> 3) + 1):
                            xa, xb = max(x0, 8 * kx), min(x1, 8 * kx + 7)
                            s = table[kz, ky, kx]
                            if s == 0:
                                hi = max(hi, 0.0)
                                lo = min(lo, 0.0)
                            elif (za == 8 * kz and ya == 8 * ky and xa == 8 * kx
                                  and zb == min(8 * kz + 7, nz - 1)
                                  and yb == min(8 * ky + 7, ny - 1)
                                  and xb == min(8 * kx + 7, nx - 1)):
                                hi = max(hi, smax[s])
                                lo = min(lo, smin[s])
                            else:
                                for z in range(za, zb + 1):
                                    for y in range(ya, yb + 1):
                                        for x in range(xa, xb + 1):
                                            v = pool[s, z & 7, y & 7, x & 7]
                                            hi = max(hi, v)
                                            lo = min(lo, v)
                mx[cz, cy, cx] = hi
                mn[cz, cy, cx] = lo


def majorant_from_bricks(table, pool, dims, resolution=None):
    """(maxima, minima) float32 [cz, cy, cx] of a brick grid: exactly
    ``build_majorant_grid(dense, resolution)`` (majorant.py), without the dense array.

    resolution: (cz, cy, cx) equal cells over the box; None for the brick grid (bz, by, bx),
    whose cells are the bricks when every dim is a multiple of 8 (see the module docstring
    for other dims). Cells whose influence box holds only empty bricks get 0 and 0 and cost
    nothing to build."""
    nx, ny, nz = _dims(dims)
    res = table.shape if resolution is None else tuple(int(r) for r in resolution)
    if len(res) != 3 or min(res) < 1:
        raise ValueError(f"majorant resolution must be 3 positive integers, got {resolution}")
    ranges, brick_cells = [], []
    for n, c, nb in zip((nz, ny, nx), res, table.shape):
        lo, hi = influence_ranges(n, c)
        ranges.append(np.stack([lo, hi], 1).astype(np.int64))
        # Cells whose range [lo, hi] meets brick k's voxels [8k, min(8k + 7, n - 1)]: lo and
        # hi are non-decreasing in the cell index.
        first = 8 * np.arange(nb)
        last = np.minimum(first + 7, n - 1)
        brick_cells.append(np.stack([np.searchsorted(hi, first, "left"),
                                     np.searchsorted(lo, last, "right") - 1], 1).astype(np.int64))
    smax = np.zeros(len(pool), pool.dtype)
    smin = np.zeros(len(pool), pool.dtype)
    _slot_extrema(table, pool, nx, ny, nz, smax, smin)
    mark = np.zeros(res, np.uint8)
    _mark_cells(table, brick_cells[0], brick_cells[1], brick_cells[2], mark)
    mx = np.zeros(res, pool.dtype)
    mn = np.zeros(res, pool.dtype)
    _cell_extrema(table, pool, nx, ny, nz, ranges[0], ranges[1], ranges[2], smax, smin, mark,
                  mx, mn)
    return mx.astype(np.float32, copy=False), mn.astype(np.float32, copy=False)
