"""A density grid kept as 8^3 bricks (volmc/reference/sparse_grid.py has the storage), so a
mostly empty grid costs memory in proportion to its non-empty bricks.

``BrickGrid`` stands in for the dense float32 array [z, y, x] where the scene code looks at
a grid (shape, size, max, min); ``np.asarray`` builds the dense array, which only tests,
peers and benchmarks ask for. OpenVDB/NanoVDB densities load straight into one from the
file's 8^3 leaves (loading.py); any grid becomes one when ``render.grid_storage`` says so.
"""

import numpy as np

from ..reference.sparse_grid import (bricks_from_blocks, bricks_from_dense, sparse_nbytes,
                                     sparse_to_dense)


class BrickGrid:
    """A grid of dims (nx, ny, nz) voxels as an index ``table`` int32 [bz, by, bx] into a
    ``pool`` float32 [n_slots, 8, 8, 8] (slot 0: the shared empty brick)."""

    ndim = 3
    dtype = np.dtype(np.float32)

    def __init__(self, table, pool, dims):
        self.table = np.ascontiguousarray(table, np.int32)
        self.pool = np.ascontiguousarray(pool, np.float32)
        self.dims = tuple(int(v) for v in dims)

    @classmethod
    def from_dense(cls, grid):
        nz, ny, nx = grid.shape
        return cls(*bricks_from_dense(grid), (nx, ny, nz))

    @classmethod
    def from_blocks(cls, dims, origins, values):
        """From 8^3 blocks (voxel origins (x, y, z) relative to the grid), never dense."""
        return cls(*bricks_from_blocks(dims, origins, values), dims)

    @property
    def shape(self):
        nx, ny, nz = self.dims
        return (nz, ny, nx)

    @property
    def size(self):
        return int(np.prod(self.shape, dtype=np.int64))

    @property
    def nbytes(self):
        """Bytes of the table and the pool."""
        return sparse_nbytes(self.table, self.pool)

    @property
    def occupancy(self):
        """Fraction of bricks that are not empty."""
        return float(np.count_nonzero(self.table)) / self.table.size

    def max(self):
        """Largest voxel (the pool's padding and empty slot hold 0, and voxels are >= 0)."""
        return self.pool.max()

    def min(self):
        """A lower bound of the voxels: 0 when any brick is empty or padded, else exact."""
        if np.any(self.table == 0) or any(d % 8 for d in self.dims):
            return np.float32(0.0)
        return self.pool[1:].min()

    def __array__(self, dtype=None, copy=None):
        dense = sparse_to_dense(self.table, self.pool, self.dims)
        return dense if dtype is None else dense.astype(dtype)

    def astype(self, dtype):
        return np.asarray(self, dtype)


def stores_bricks(scene):
    """True when the kernels read the scene's density from bricks: render.grid_storage =
    "bricks", or "auto" with a grid loaded as bricks (a VDB file)."""
    how = scene.render.grid_storage
    return scene.grid is not None and (how == "bricks" or
                                       (how == "auto" and isinstance(scene.grid, BrickGrid)))


def density_storage(scene):
    """The scene's grid as the kernels will read it: a BrickGrid when ``stores_bricks``, else
    the dense array; None when homogeneous."""
    g = scene.grid
    if g is None:
        return None
    if stores_bricks(scene):
        return g if isinstance(g, BrickGrid) else BrickGrid.from_dense(g)
    return np.asarray(g) if isinstance(g, BrickGrid) else g
