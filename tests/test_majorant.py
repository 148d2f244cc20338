"""Majorant grids: per-cell bounds that hold under trilinear interpolation (issue 5's first
piece; the DDA walk that uses them comes next)."""

import numpy as np
import pytest
from numba import njit, prange

from volmc.reference.grid import grid_lookup
from volmc.reference.majorant import (auto_resolution, build_majorant_grid, cell_of,
                                      influence_ranges)


@njit(cache=True, parallel=True)
def _lookups(grid, bmin, inv_ext, pts):
    out = np.empty(pts.shape[0])
    for i in prange(pts.shape[0]):
        out[i] = grid_lookup(grid, bmin, inv_ext, (pts[i, 0], pts[i, 1], pts[i, 2]))
    return out


def _check_bounds(grid, res, n_points, seed):
    bmin, bmax = np.array([-1.0, -0.5, 0.0]), np.array([1.0, 1.5, 3.0])
    mx, mn = build_majorant_grid(grid, res)
    rng = np.random.default_rng(seed)
    pts = bmin + rng.random((n_points, 3)) * (bmax - bmin)
    # Points exactly on cell faces and box faces too: the bound must hold on both sides.
    faces = bmin + np.stack(np.meshgrid(*[np.linspace(0, 1, r + 1) for r in mx.shape[::-1]],
                                        indexing="ij"), -1).reshape(-1, 3) * (bmax - bmin)
    pts = np.concatenate([pts, faces])
    vals = _lookups(grid.astype(np.float64), tuple(bmin), tuple(1.0 / (bmax - bmin)), pts)
    iz, iy, ix = cell_of(pts, bmin, bmax, mx.shape)
    assert np.all(vals <= mx[iz, iy, ix].astype(np.float64) * (1 + 1e-7) + 1e-30)
    assert np.all(vals >= mn[iz, iy, ix].astype(np.float64) * (1 - 1e-7) - 1e-30)
    # Cell-face points belong to two cells: check the neighbour cell's bound as well.
    iz2, iy2, ix2 = cell_of(pts - 1e-9, bmin, bmax, mx.shape)
    assert np.all(vals <= mx[iz2, iy2, ix2].astype(np.float64) * (1 + 1e-7) + 1e-30)
    return mx, mn


def _shipped_grid_scenes():
    from volmc.resources import scenes_dir
    from volmc.scene import load_scene
    out = []
    for path in sorted(scenes_dir().glob("*.toml")) + sorted(scenes_dir().glob("tests/*.toml")):
        if load_scene(path).grid is not None:
            out.append(path.name)
    return out


SHIPPED_GRIDS = _shipped_grid_scenes()


@pytest.mark.parametrize("name", SHIPPED_GRIDS)
def test_bounds_hold_at_a_million_points_on_every_shipped_grid(name):
    from volmc.resources import scenes_dir
    from volmc.scene import load_scene
    path = scenes_dir() / name if (scenes_dir() / name).exists() else scenes_dir() / "tests" / name
    scene = load_scene(path)
    res = scene.render.majorant_resolution or None
    mx, mn = _check_bounds(scene.grid, res, 1_000_000, 1)
    assert mx.max() == scene.grid.max()
    if name == "cloud.toml":
        assert mx.shape == (16, 16, 16)
        # Not trivially loose: most of the cloud's cells are empty (bound 0, no lookups).
        assert np.mean(mx == 0) > 0.3


def test_every_kind_of_shipped_grid_is_covered():
    assert {"cloud.toml", "white_furnace.toml", "constant_grid.toml"} <= set(SHIPPED_GRIDS)


@pytest.mark.parametrize("shape,res", [((8, 8, 8), (3, 5, 2)), ((5, 7, 9), None),
                                       ((1, 1, 1), (2, 2, 2)), ((13, 2, 6), (13, 2, 6)),
                                       ((4, 4, 4), (9, 9, 9))])
def test_bounds_hold_on_random_grids(shape, res):
    grid = np.random.default_rng(3).random(shape).astype(np.float32) ** 3
    _check_bounds(grid, res, 200_000, 2)


def test_single_voxel_is_not_missed():
    grid = np.zeros((16, 16, 16), np.float32)
    grid[9, 4, 13] = 2.0
    mx, mn = build_majorant_grid(grid, (4, 4, 4))
    assert mx.max() == 2.0 and mn.max() == 0.0
    # Every cell the voxel can influence carries it, and no other cell does.
    _check_bounds(grid, (4, 4, 4), 200_000, 5)
    assert 1 <= np.count_nonzero(mx) <= 8


def test_influence_ranges_and_auto_resolution():
    lo, hi = influence_ranges(8, 2)   # cells cover voxel coords [-0.5, 3.5] and [3.5, 7.5]
    assert list(lo) == [0, 3] and list(hi) == [4, 7]
    assert auto_resolution((128, 128, 128)) == (16, 16, 16)
    assert auto_resolution((1, 600, 9)) == (1, 64, 2)
    with pytest.raises(ValueError):
        build_majorant_grid(np.ones((2, 2, 2)), (0, 1, 1))
