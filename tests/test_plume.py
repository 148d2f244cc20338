"""Tests for the procedural smoke plume (volmc.scene.generators.plume): density and
temperature grids."""

import time

import numpy as np
import pytest

from volmc.scene.generators import PLUME_T_AMBIENT, PLUME_T_CORE, plume


def _centres(n):
    return (np.arange(n) + 0.5) / n


def _coords(shape):
    """Voxel-centre coordinates (Z, Y, X) of a [z, y, x] grid in the unit cube."""
    nz, ny, nx = shape
    return np.meshgrid(_centres(nz), _centres(ny), _centres(nx), indexing="ij")


def _near_face_mask(shape, margin):
    """True for voxels whose centre is within `margin` of a face."""
    m = np.zeros(shape, dtype=bool)
    for c in _coords(shape):
        m |= (c < margin) | (c > 1.0 - margin)
    return m


@pytest.fixture(scope="module")
def plumes64():
    return {s: plume(64, seed=s) for s in (0, 1, 2, 3)}


def test_shapes_dtypes_int_resolution():
    d, t = plume(24, seed=3)
    for a in (d, t):
        assert a.shape == (24, 24, 24)
        assert a.dtype == np.float32
        assert a.flags.c_contiguous


@pytest.mark.parametrize("res", [(20, 28, 12), [16, 8, 24], np.array([10, 14, 18])])
def test_shapes_non_cubic_sequence(res):
    nx, ny, nz = (int(v) for v in res)
    d, t = plume(res, seed=1)
    for a in (d, t):
        assert a.shape == (nz, ny, nx)
        assert a.dtype == np.float32
        assert a.flags.c_contiguous
    assert d.max() > 0.0


@pytest.mark.parametrize("bad", [(8, 8), (8, 8, 8, 8), 0, (8, -1, 8), "16"])
def test_bad_resolution_rejected(bad):
    with pytest.raises((ValueError, TypeError)):
        plume(bad)


def test_ranges_and_finite(plumes64):
    for d, t in plumes64.values():
        assert np.all(np.isfinite(d)) and np.all(np.isfinite(t))
        assert d.min() >= 0.0 and d.max() <= 1.0
        assert d.max() > 0.99            # a dense core, not just a haze
        assert t.min() == PLUME_T_AMBIENT == 300.0
        assert t.max() <= PLUME_T_CORE == 1800.0
        assert t.max() > 1500.0          # it glows


def test_zero_at_faces(plumes64):
    for d, t in list(plumes64.values()) + [plume((40, 52, 36), seed=4)]:
        face = _near_face_mask(d.shape, 0.05)
        assert np.all(d[face] == 0.0)
        assert np.all(t[face] == PLUME_T_AMBIENT)
        # Not cut by the margin either: a band a little wider is (almost) empty.
        assert d[_near_face_mask(d.shape, 0.07)].max() < 0.05


def test_deterministic_per_seed():
    a = plume(32, seed=7)
    # Global numpy RNG state must not matter.
    np.random.seed(123)
    np.random.random(1000)
    b = plume(32, seed=7)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_different_seeds_differ(plumes64):
    for s, u in ((0, 1), (1, 2), (2, 3)):
        a, b = plumes64[s][0], plumes64[u][0]
        sa, sb = a > 0, b > 0
        assert (sa & sb).sum() / (sa | sb).sum() < 0.8
        assert np.abs(a - b).mean() > 0.3 * a.mean()
        assert not np.array_equal(plumes64[s][1], plumes64[u][1])


def test_exact_resolution_independence():
    # Voxel i of an m-grid and voxel 3i+1 of a 3m-grid share their centre, so both grids
    # sample the same point of the same continuous fields.
    d0, t0 = plume((16, 20, 12), seed=2)
    d1, t1 = plume((48, 60, 36), seed=2)
    np.testing.assert_allclose(d1[1::3, 1::3, 1::3], d0, rtol=0, atol=1e-5)
    np.testing.assert_allclose(t1[1::3, 1::3, 1::3], t0, rtol=0, atol=1e-2)


def test_resolution_independence_downsampled(plumes64):
    d0, t0 = plumes64[0]
    d1, t1 = plume(128, seed=0)
    d1 = d1.reshape(64, 2, 64, 2, 64, 2).mean(axis=(1, 3, 5))
    t1 = t1.reshape(64, 2, 64, 2, 64, 2).mean(axis=(1, 3, 5))
    assert np.corrcoef(d0.ravel(), d1.ravel())[0, 1] > 0.98
    assert np.abs(d0 - d1).mean() < 0.15 * d0.mean()
    assert np.corrcoef(t0.ravel(), t1.ravel())[0, 1] > 0.98
    # The soft edge too, not only the empty space and the solid core.
    shell = ((d0 > 0) & (d0 < 1)) | ((d1 > 0) & (d1 < 1))
    assert np.corrcoef(d0[shell], d1[shell])[0, 1] > 0.95


def _band(d, lo, hi):
    """Density-weighted horizontal spread (RMS distance from the centroid), mean non-zero
    density and mass of the slab lo <= y < hi."""
    z, y, x = _coords(d.shape)
    w = d * ((y >= lo) & (y < hi))
    m = w.sum()
    cx, cz = (w * x).sum() / m, (w * z).sum() / m
    spread = np.sqrt((w * ((x - cx) ** 2 + (z - cz) ** 2)).sum() / m)
    return spread, d[(w > 0)].mean(), m


def test_rising_column_widens_and_thins(plumes64):
    for d, _ in plumes64.values():
        y = _coords(d.shape)[1]
        # Starts above the floor, ends below the ceiling, mass low down.
        assert y[d > 0].min() > 0.08 and y[d > 0].max() < 0.95
        base_spread, base_mean, _ = _band(d, 0.1, 0.25)
        mid_spread, mid_mean, _ = _band(d, 0.45, 0.6)
        top_spread, top_mean, top_mass = _band(d, 0.75, 0.9)
        assert mid_spread > 1.5 * base_spread
        assert base_mean > 0.5                   # dense near the source ...
        assert mid_mean < 0.6 * base_mean        # ... thinning as it rises ...
        assert top_mean < 0.15 * base_mean       # ... to faint wisps at the top
        assert 0 < top_mass < 0.2 * d.sum()


def test_hot_core_is_dense_and_low(plumes64):
    for d, t in plumes64.values():
        y = _coords(d.shape)[1]
        core = (d >= 0.95) & (y < 0.2)
        assert core.sum() > 20
        assert np.median(t[core]) > 900.0        # the dense core near the source glows
        hot = t > 1000.0
        assert hot.sum() > 0
        assert d[hot].min() > 0.5                # what glows is dense smoke ...
        assert y[hot].max() < 0.3                # ... near the base
        assert t[y > 0.5].max() < 500.0          # the smoke has cooled higher up
        # Temperature follows the density: hot only where there is smoke.
        assert np.all(t[d == 0] < 400.0)
        assert np.corrcoef(d.ravel(), t.ravel())[0, 1] > 0.6


def test_connected(plumes64):
    # The plume is one body: the wisps trail off it rather than float as debris.
    ndimage = pytest.importorskip("scipy.ndimage")
    for d, _ in plumes64.values():
        lab, _ = ndimage.label(d > 0)
        mass = np.bincount(lab.ravel(), weights=d.ravel().astype(np.float64))[1:]
        assert mass.max() > 0.99 * mass.sum()


def test_runtime_128():
    plume(8)                                     # compile (or load the numba cache)
    t0 = time.perf_counter()
    plume(128, seed=5)
    # About 0.5 s on 2 cores; the bound leaves room for a loaded machine.
    assert time.perf_counter() - t0 < 10.0
