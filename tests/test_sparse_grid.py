"""Sparse brick grids (volmc/reference/sparse_grid.py, sparse_lookup in kernels/grid.h): the
lookup is the dense lookup bit for bit, the builders agree with each other and never build
the dense array, and the brick-aligned majorant is build_majorant_grid's."""

import tracemalloc

import numpy as np
import pytest
from numba import njit

from cl_harness import f3, i3, out_buf, run, to_dev
from volmc.reference.grid import grid_lookup
from volmc.reference.majorant import build_majorant_grid, cell_of
from volmc.reference.sparse_grid import (brick_shape, bricks_from_blocks, bricks_from_dense,
                                         majorant_from_bricks, sparse_lookup, sparse_nbytes,
                                         sparse_to_dense)


BMIN = (-1.0, -0.5, -2.0)
BMAX = (1.0, 1.5, 0.25)
INV_EXT = tuple(1.0 / (b - a) for a, b in zip(BMIN, BMAX))

#: (nx, ny, nz): multiples of 8, not, single voxels and single bricks.
SHAPES = [(16, 24, 8), (33, 17, 20), (1, 9, 8), (7, 1, 1), (8, 8, 8), (40, 3, 17)]


@njit(cache=True)
def _both(grid, table, pool, dims, bmin, inv_ext, pts):
    out = np.empty((pts.shape[0], 2))
    for i in range(pts.shape[0]):
        p = (pts[i, 0], pts[i, 1], pts[i, 2])
        out[i, 0] = grid_lookup(grid, bmin, inv_ext, p)
        out[i, 1] = sparse_lookup(table, pool, dims, bmin, inv_ext, p)
    return out


def _sparse_grid(dims, fill, seed):
    """Random grid [nz, ny, nx] float32 with about ``fill`` of its voxels non-zero, in clumps
    so that some bricks are full, some partial and some empty."""
    nx, ny, nz = dims
    rng = np.random.default_rng(seed)
    g = rng.random((nz, ny, nx)).astype(np.float32) + np.float32(0.01)
    keep = rng.random((nz, ny, nx)) < fill
    for _ in range(3):   # clump: a voxel survives if one of its x/y/z neighbours does
        keep = keep | np.roll(keep, 1, 0) & (rng.random(keep.shape) < 0.5)
        keep = keep | np.roll(keep, 1, 2) & (rng.random(keep.shape) < 0.5)
    g[~keep] = 0.0
    return g


def _points(dims, n, seed):
    """Random points in the box, plus points on box faces and corners, voxel centres and
    brick boundaries (voxel coordinates 7, 7.5, 8, 15.5 ...), and half-voxel clamp zones."""
    rng = np.random.default_rng(seed)
    lo, hi = np.array(BMIN), np.array(BMAX)
    pts = [lo + rng.random((n, 3)) * (hi - lo)]
    d = np.array(dims, float)
    for a in range(3):
        s = np.arange(0.0, d[a] + 0.1, 0.25)       # voxel coordinates along axis a
        s = np.concatenate([s, np.nextafter(s, -1.0)[1:]])
        q = lo + rng.random((len(s), 3)) * (hi - lo)
        q[:, a] = lo[a] + s / d[a] * (hi[a] - lo[a])
        pts.append(q)
    corners = np.array([[lo[0] if i & 1 else hi[0], lo[1] if i & 2 else hi[1],
                         lo[2] if i & 4 else hi[2]] for i in range(8)])
    pts.append(corners)
    return np.concatenate(pts)


@pytest.mark.parametrize("dims", SHAPES)
@pytest.mark.parametrize("fill", [0.0, 0.02, 0.3, 1.0])
def test_reference_lookup_equals_dense_bit_for_bit(dims, fill):
    g = _sparse_grid(dims, fill, 1)
    table, pool = bricks_from_dense(g)
    assert table.shape == brick_shape(dims) and table.dtype == np.int32
    pts = _points(dims, 20_000, 2)
    out = _both(g.astype(np.float64), table, pool.astype(np.float64), dims, BMIN, INV_EXT, pts)
    assert np.array_equal(out[:, 0].view(np.int64), out[:, 1].view(np.int64))


def test_reference_lookup_in_float32_is_the_dense_float32_lookup():
    """With float32 arrays (pool and dense grid) the reference still equals grid_lookup bit
    for bit: the same voxels with the same weights."""
    dims = (33, 17, 20)
    g = _sparse_grid(dims, 0.1, 3)
    table, pool = bricks_from_dense(g)
    out = _both(g, table, pool, dims, BMIN, INV_EXT, _points(dims, 20_000, 4))
    assert np.array_equal(out[:, 0], out[:, 1])


@pytest.mark.parametrize("dims", [(33, 17, 20), (16, 24, 8), (1, 9, 8)])
def test_kernel_lookup_equals_reference_and_dense_kernel(dims, lanes):
    g = _sparse_grid(dims, 0.1, 5)
    table, pool = bricks_from_dense(g)
    pts = _points(dims, 20_000, 6).astype(np.float32)
    n = len(pts)
    sparse, sb = out_buf(n)
    run("t_sparse_lookup", n, to_dev(table), to_dev(pool), i3(dims), f3(BMIN), f3(INV_EXT),
        to_dev(pts.ravel()), sb, outs=[(sparse, sb)])
    dense, db = out_buf(n)
    run("t_grid_lookup", n, to_dev(g), i3(dims), f3(BMIN), f3(INV_EXT), to_dev(pts.ravel()), db,
        outs=[(dense, db)])
    # The same float32 operations on the same voxels as the dense kernel: identical.
    assert np.array_equal(sparse.view(np.int32), dense.view(np.int32))
    inv32 = tuple(float(np.float32(x)) for x in INV_EXT)
    ref = _both(g.astype(np.float64), table, pool.astype(np.float64), dims, BMIN, inv32,
                pts.astype(np.float64))[:, 1]
    # Against the float64 reference: float32 rounding of the voxel coordinate x (up to a few
    # ulps of max(dims)) moves the weights, so the error is absolute, relative to the grid's
    # magnitude; 1e-6 relative to the value on top of it. (Observed: 2e-6 for dims 33.)
    eps = 2.0**-24
    atol = 4 * eps * max(dims) * float(g.max())
    assert np.all(np.abs(sparse - ref) <= atol + 1e-6 * np.abs(ref))


def test_dense_builder_layout():
    dims = (20, 9, 17)
    g = np.zeros((17, 9, 20), np.float32)
    g[16, 8, 19] = 3.0          # the last, partial brick
    g[0, 0, 0] = 1.0            # the first
    g[9, 2, 12] = -0.0          # negative zero is zero
    table, pool = bricks_from_dense(g)
    assert table.shape == (3, 2, 3)
    assert pool.shape == (3, 8, 8, 8) and pool.dtype == np.float32
    assert not pool[0].any()
    # Slots in raster order of the brick index; all other bricks share slot 0.
    assert table[0, 0, 0] == 1 and table[2, 1, 2] == 2 and np.count_nonzero(table) == 2
    assert pool[1, 0, 0, 0] == 1.0 and pool[2, 16 & 7, 8 & 7, 19 & 7] == 3.0
    assert np.array_equal(sparse_to_dense(table, pool, dims), g)
    t64, p64 = bricks_from_dense(g, np.float64)
    assert p64.dtype == np.float64 and np.array_equal(t64, table)


def _blocks_of(g, offset, drop_empty=True):
    """Cut dense g [nz, ny, nx] into 8^3 blocks whose minimum corners sit at offset + 8 k
    (offset (x, y, z), any integers), as OpenVDB leaves of a grid whose bounding box does not
    start on a multiple of 8. Blocks hang over every face."""
    nz, ny, nx = g.shape
    ox, oy, oz = (o % 8 - 8 if o % 8 else 0 for o in offset)
    pad = np.zeros((nz + 16, ny + 16, nx + 16), g.dtype)
    pad[8:8 + nz, 8:8 + ny, 8:8 + nx] = g
    origins, values = [], []
    for z in range(oz, nz, 8):
        for y in range(oy, ny, 8):
            for x in range(ox, nx, 8):
                v = pad[z + 8:z + 16, y + 8:y + 16, x + 8:x + 16]
                if drop_empty and not v.any():
                    continue
                origins.append((x, y, z))
                values.append(v)
    return np.array(origins, np.int64).reshape(-1, 3), np.array(values).reshape(-1, 8, 8, 8)


@pytest.mark.parametrize("dims", [(33, 17, 20), (16, 24, 8), (1, 9, 8)])
@pytest.mark.parametrize("offset", [(0, 0, 0), (3, -5, 2), (-1, 7, 4)])
def test_blocks_builder_equals_dense_builder(dims, offset):
    g = _sparse_grid(dims, 0.05, 7)
    origins, values = _blocks_of(g, offset)
    rng = np.random.default_rng(8)
    perm = rng.permutation(len(origins))   # block order does not matter
    table, pool = bricks_from_blocks(dims, origins[perm], values[perm])
    t_ref, p_ref = bricks_from_dense(g)
    assert np.array_equal(table, t_ref) and np.array_equal(pool, p_ref)
    # Blocks wholly outside the grid, and a block of zeros that later blocks overwrite,
    # change nothing.
    extra_o = np.array([[-8, 0, 0], [dims[0] + 3, 0, 0], [0, 0, 0]])
    extra_v = np.zeros((3, 8, 8, 8), np.float32)
    extra_v[:2] = 5.0
    t2, p2 = bricks_from_blocks(dims, np.concatenate([extra_o, origins]),
                                np.concatenate([extra_v, values]))
    assert np.array_equal(t2, t_ref) and np.array_equal(p2, p_ref)


def test_blocks_builder_validates_and_handles_no_blocks():
    table, pool = bricks_from_blocks((9, 9, 9), np.zeros((0, 3), int), np.zeros((0, 8, 8, 8)))
    assert table.shape == (2, 2, 2) and not table.any() and pool.shape == (1, 8, 8, 8)
    with pytest.raises(ValueError):
        bricks_from_blocks((9, 9, 9), np.zeros((2, 3), int), np.zeros((1, 8, 8, 8)))
    with pytest.raises(ValueError):
        bricks_from_blocks((9, 0, 9), np.zeros((0, 3), int), np.zeros((0, 8, 8, 8)))


def test_blocks_builder_never_builds_the_dense_array():
    """A 2048^3 grid (32 GiB dense in float32) with a few blocks, some straddling bricks:
    the builder's peak allocation is the table (64 MiB) plus small change, and lookups read
    the blocks back."""
    dims = (2048, 2048, 2048)
    rng = np.random.default_rng(9)
    origins = np.array([[0, 0, 0], [2043, 2040, 2044], [1001, 517, 1900], [1009, 517, 1900],
                        [-4, 300, 300]])
    values = (1.0 + rng.random((len(origins), 8, 8, 8))).astype(np.float32)
    bricks_from_blocks((9, 9, 9), origins[:1], values[:1])   # compile outside the trace
    tracemalloc.start()
    try:
        table, pool = bricks_from_blocks(dims, origins, values)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < table.nbytes + (8 << 20)
    # the empty brick; aligned: 1; clipped at the far corner: 1; two neighbours straddling
    # 2 x 2 x 2 bricks and sharing 4: 12; hanging over x = 0: 4
    assert len(pool) == 1 + 1 + 1 + 12 + 4
    # Voxel centres of a few block voxels read back exactly.
    ext = 1.0 / np.array(INV_EXT)
    for b, (z, y, x) in [(2, (0, 0, 0)), (3, (7, 7, 7)), (1, (3, 7, 4)), (4, (5, 2, 6))]:
        v = origins[b] + (x, y, z)
        p = np.array(BMIN) + (v + 0.5) / np.array(dims) * ext
        got = sparse_lookup(table, pool.astype(np.float64), dims, BMIN, INV_EXT, tuple(p))
        assert got == pytest.approx(float(values[b, z, y, x]), rel=1e-12)


def _check_majorant_bounds(g, dims, mx, mn, n, seed):
    """Every lookup lies within its cell's bounds (cells are equal divisions of the box)."""
    table, pool = bricks_from_dense(g)
    pts = _points(dims, n, seed)
    vals = _both(g.astype(np.float64), table, pool.astype(np.float64), dims, BMIN, INV_EXT,
                 pts)[:, 1]
    for shift in (0.0, -1e-9):     # a point on a cell face belongs to both cells
        iz, iy, ix = cell_of(pts + shift, BMIN, BMAX, mx.shape)
        assert np.all(vals <= mx[iz, iy, ix] * (1 + 1e-7))
        assert np.all(vals >= mn[iz, iy, ix] * (1 - 1e-7))


@pytest.mark.parametrize("dims", [(16, 24, 8), (32, 8, 40), (8, 8, 8)])
@pytest.mark.parametrize("fill", [0.005, 0.05, 1.0])
def test_majorant_aligned_is_build_majorant_grid_on_the_bricks(dims, fill):
    g = _sparse_grid(dims, fill, 10)
    table, pool = bricks_from_dense(g)
    mx, mn = majorant_from_bricks(table, pool, dims)
    assert mx.shape == table.shape and mx.dtype == np.float32
    bx, bn = build_majorant_grid(g, table.shape)
    assert np.array_equal(mx, bx) and np.array_equal(mn, bn)
    _check_majorant_bounds(g, dims, mx, mn, 50_000, 11)


def test_majorant_aligned_reads_one_voxel_across_each_brick_face():
    dims = (32, 32, 32)
    g = np.zeros((32, 32, 32), np.float32)
    g[8, 15, 16] = 2.0     # brick (kz, ky, kx) = (1, 1, 2), on its low-z, high-y, low-x faces
    table, pool = bricks_from_dense(g)
    mx, mn = majorant_from_bricks(table, pool, dims)
    hit = {tuple(int(c) for c in k) for k in np.argwhere(mx > 0)}
    assert hit == {(z, y, x) for z in (0, 1) for y in (1, 2) for x in (1, 2)}
    assert mx.max() == 2.0 and not mn.any()
    # Grid edge: the last brick clamps instead of reading a neighbour.
    g2 = np.zeros((32, 32, 32), np.float32)
    g2[31, 31, 31] = 1.0
    mx2, _ = majorant_from_bricks(*bricks_from_dense(g2), dims)
    assert {tuple(int(c) for c in k) for k in np.argwhere(mx2 > 0)} == {(3, 3, 3)}


def test_majorant_constant_brick_is_homogeneous_and_empty_neighbourhoods_are_zero():
    dims = (32, 16, 24)
    g = np.zeros((24, 16, 32), np.float32)
    g[7:17, 7:17, 7:17] = 0.5    # brick (1, 1, 1) and a one-voxel layer around it: constant
    mx, mn = majorant_from_bricks(*bricks_from_dense(g), dims)
    assert mx[1, 1, 1] == mn[1, 1, 1] == 0.5
    assert mx[0, 0, 3] == 0.0 and mx[2, 1, 3] == 0.0
    assert np.array_equal(mx, build_majorant_grid(g, mx.shape)[0])


@pytest.mark.parametrize("dims", [(33, 17, 20), (1, 9, 8), (40, 3, 17)])
@pytest.mark.parametrize("resolution", [None, (3, 5, 2), (1, 1, 1), (20, 17, 33)])
def test_majorant_unaligned_and_other_resolutions_equal_build_majorant_grid(dims, resolution):
    """Dims not multiples of 8: the cells divide the box equally, as the DDA walks them, and
    straddle bricks; the bounds are still build_majorant_grid's exactly."""
    g = _sparse_grid(dims, 0.03, 12)
    table, pool = bricks_from_dense(g)
    mx, mn = majorant_from_bricks(table, pool, dims, resolution)
    bx, bn = build_majorant_grid(g, table.shape if resolution is None else resolution)
    assert np.array_equal(mx, bx) and np.array_equal(mn, bn)
    _check_majorant_bounds(g, dims, mx, mn, 20_000, 13)


def _ball_blocks(dims, centre, radius):
    """8^3 blocks (brick-aligned) of a ball of density 1 - (r / radius)^2 in a grid."""
    lo = np.maximum((np.array(centre) - radius) // 8 * 8, 0).astype(int)
    hi = np.minimum(np.array(centre) + radius + 1, dims).astype(int)
    ax = [np.arange(a, b, 8) for a, b in zip(lo, hi)]
    ox, oy, oz = np.meshgrid(*ax, indexing="ij")
    origins = np.stack([ox.ravel(), oy.ravel(), oz.ravel()], 1)
    k = np.arange(8)
    z = origins[:, 2, None, None, None] + k[None, :, None, None] + 0.5
    y = origins[:, 1, None, None, None] + k[None, None, :, None] + 0.5
    x = origins[:, 0, None, None, None] + k[None, None, None, :] + 0.5
    r2 = ((x - centre[0]) ** 2 + (y - centre[1]) ** 2 + (z - centre[2]) ** 2) / radius**2
    return origins, np.maximum(1.0 - r2, 0.0).astype(np.float32)


def test_memory_of_a_512_cubed_grid_at_three_percent():
    dims = (512, 512, 512)
    radius = (0.03 * 512**3 * 3 / (4 * np.pi)) ** (1 / 3)
    origins, values = _ball_blocks(dims, (250.0, 260.0, 270.0), radius)
    table, pool = bricks_from_blocks(dims, origins, values)
    active = int(np.count_nonzero(values))
    assert 0.025 < active / 512**3 < 0.035
    dense_bytes = 512**3 * 4
    # Boundary bricks are partly empty: the pool stays within 2x the active voxels' bytes.
    assert pool.nbytes < 2 * 4 * active
    assert sparse_nbytes(table, pool) < 0.06 * dense_bytes
    mx, mn = majorant_from_bricks(table, pool, dims)
    assert mx.max() == values.max() and np.count_nonzero(mx) < 0.06 * mx.size


def test_benchmark_kernel_and_twin_read_the_same_points(lanes):
    """volmc/bench/sparse.py: the kernel and its Numba twin sum lookups at the same points
    (float32 against float64 positions, so nearly equal), and a small run reports sparse sums
    equal to the dense ones on both backends (no timing is checked)."""
    from volmc.bench.sparse import (LOOKUPS, MODES, OpenCLSparseBench, bench_sums, blobs_grid,
                                    run)
    g = blobs_grid(48, 0.05, 3)
    table, pool = bricks_from_dense(g)
    bricks = np.ascontiguousarray(np.argwhere(table)[:, ::-1], np.int32)
    bmin, bmax = (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)
    ocl = OpenCLSparseBench(g, table, pool, bricks, bmin, bmax)
    for m in range(len(MODES)):
        for k in range(len(LOOKUPS)):
            a = ocl.sums(k, m, 512, 32, 7)
            b = bench_sums(k, g.astype(np.float64), table, pool.astype(np.float64), (48,) * 3,
                           bmin, bmax, bricks, m, 512, 32, 7)
            assert np.allclose(a, b, rtol=1e-4, atol=1e-4 * 32), (MODES[m], LOOKUPS[k])
    r = run(size=40, fill=0.05, lookups=1 << 12, per_item=16, repeats=1, log=lambda s: None)
    assert all(r["identical"].values()) and len(r["identical"]) == 6
    assert r["bytes"]["table"] + r["bytes"]["pool_f32"] < r["bytes"]["dense_f32"]
