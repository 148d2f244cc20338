"""Tests for the procedural cumulus generator (volmc.scene.generators.cloud)."""

import numpy as np
import pytest

from volmc.scene.generators import cloud


def _centres(n):
    return (np.arange(n) + 0.5) / n


def _near_face_mask(shape, margin):
    """True for voxels (array [z, y, x]) whose centre is within `margin` of a face."""
    nz, ny, nx = shape
    z, y, x = np.meshgrid(_centres(nz), _centres(ny), _centres(nx), indexing="ij")
    m = np.zeros(shape, dtype=bool)
    for c in (x, y, z):
        m |= (c < margin) | (c > 1.0 - margin)
    return m


def _surface_ratio(d):
    """Isosurface area of a density in [0, 1] relative to a sphere of the same
    volume.  By the coarea formula the integral of |grad d| is the mean area of
    the level sets, so this is ~1 for a ball and grows with surface detail."""
    n = d.shape[0]
    g = np.gradient(d.astype(np.float64), 1.0 / n)
    area = np.sqrt(sum(c * c for c in g)).sum() / n**3
    vol = d.sum() / n**3
    return area / ((36.0 * np.pi) ** (1.0 / 3.0) * vol ** (2.0 / 3.0))


@pytest.fixture(scope="module")
def clouds64():
    return {s: cloud(64, seed=s) for s in (0, 1, 2)}


@pytest.fixture(scope="module")
def cloud128():
    return cloud(128, seed=0)


def test_shape_dtype_int_resolution():
    d = cloud(24, seed=3)
    assert d.shape == (24, 24, 24)
    assert d.dtype == np.float32
    assert d.flags.c_contiguous


@pytest.mark.parametrize("res", [(20, 28, 12), [16, 8, 24], np.array([10, 14, 18])])
def test_shape_non_cubic_sequence(res):
    nx, ny, nz = (int(v) for v in res)
    d = cloud(res, seed=1)
    assert d.shape == (nz, ny, nx)
    assert d.dtype == np.float32
    assert d.flags.c_contiguous
    assert d.max() > 0.0


@pytest.mark.parametrize("bad", [(8, 8), (8, 8, 8, 8), 0, (8, -1, 8), "16"])
def test_bad_resolution_rejected(bad):
    with pytest.raises((ValueError, TypeError)):
        cloud(bad)


def test_range_and_finite(clouds64):
    for d in clouds64.values():
        assert np.all(np.isfinite(d))
        assert d.min() >= 0.0
        assert d.max() <= 1.0
        # Dense core: the maximum is reached, not just approached.
        assert d.max() == 1.0


def test_zero_near_faces(clouds64):
    for d in list(clouds64.values()) + [cloud((40, 52, 36), seed=4)]:
        assert np.all(d[_near_face_mask(d.shape, 0.05)] == 0.0)


def test_cloud_not_cut_by_margin(clouds64):
    # The layout keeps clear of the hard 5 % cut, so a band slightly wider
    # than it is empty too: the cloud is never sliced flat by the box.
    for d in clouds64.values():
        assert np.all(d[_near_face_mask(d.shape, 0.06)] == 0.0)


def test_deterministic_per_seed():
    a = cloud(32, seed=7)
    # Global numpy RNG state must not matter.
    np.random.seed(123)
    np.random.random(1000)
    b = cloud(32, seed=7)
    assert np.array_equal(a, b)


def test_different_seeds_differ(clouds64):
    for s, t in ((0, 1), (1, 2)):
        a, b = clouds64[s], clouds64[t]
        sa, sb = a > 0, b > 0
        iou = (sa & sb).sum() / (sa | sb).sum()
        assert iou < 0.9
        assert np.abs(a - b).mean() > 0.15 * a.mean()


def test_exact_resolution_independence():
    # Voxel i of an m-grid and voxel 3i+1 of a 3m-grid share their centre, so
    # they sample the same point of the same continuous density.
    coarse = cloud((16, 20, 12), seed=2)
    fine = cloud((48, 60, 36), seed=2)
    np.testing.assert_allclose(fine[1::3, 1::3, 1::3], coarse, rtol=0, atol=1e-5)


def test_resolution_independence_downsampled(clouds64, cloud128):
    a = clouds64[0]
    b = cloud128.reshape(64, 2, 64, 2, 64, 2).mean(axis=(1, 3, 5))
    assert np.corrcoef(a.ravel(), b.ravel())[0, 1] > 0.98
    assert np.abs(a - b).mean() < 0.05 * a.mean()
    # The same must hold in the detailed boundary shell, not only thanks to
    # the large empty and solid regions.
    shell = ((a > 0) & (a < 1)) | ((b > 0) & (b < 1))
    assert np.corrcoef(a[shell], b[shell])[0, 1] > 0.9


def test_fill_fraction(cloud128):
    fills = [float(np.mean(cloud128 > 0))]
    fills += [float(np.mean(cloud(96, seed=s) > 0)) for s in (1, 2)]
    for f in fills:
        assert 0.12 <= f <= 0.35, fills


def test_dense_interior_thin_shell(clouds64):
    for d in clouds64.values():
        nonzero = d[d > 0]
        # Most of the cloud is core (density ~1) ...
        assert np.mean(nonzero > 0.99) > 0.5
        # ... but there is a soft shell, not a hard binary edge.
        assert np.mean(nonzero < 0.5) > 0.03


def test_flat_base_billowy_top(clouds64):
    # Cumulus: the base is a nearly flat plane near the bottom while the top
    # is a set of turrets at many heights.  Compare the spread of the lowest
    # and highest solid voxel over columns where the cloud is thick.
    for d in clouds64.values():
        n = d.shape[1]
        solid = d >= 0.5
        ys = np.arange(n)[None, :, None]
        bottom = np.where(solid, ys, n).min(axis=1) / n  # [z, x]
        top = np.where(solid, ys, -1).max(axis=1) / n
        thick = (top - bottom) > 0.25
        assert thick.sum() > 0.1 * thick.size
        assert np.median(bottom[thick]) < 0.25
        assert np.median(top[thick]) > 0.5
        assert bottom[thick].std() < 0.15 * top[thick].std()
        assert top[thick].std() > 0.05


def test_surface_detail(clouds64, cloud128):
    # A smooth dome has a ratio near 1 (a flat-bottomed half ellipsoid ~1.2);
    # the puff hierarchy plus the noise erosion wrinkle the surface well
    # beyond that, at both resolutions.
    for d in list(clouds64.values()) + [cloud128]:
        assert _surface_ratio(d) > 1.3


def test_not_fragmented(clouds64):
    # Detail must not come from scattered debris: the non-zero voxels are
    # essentially one connected body.
    ndimage = pytest.importorskip("scipy.ndimage")
    for d in clouds64.values():
        lab, n = ndimage.label(d > 0)
        sizes = np.bincount(lab.ravel())[1:]
        assert sizes.max() > 0.98 * sizes.sum()
