"""The held-out fbm clouds of the benchmarks (volmc/bench/fbm.py)."""

import numpy as np
import pytest

from volmc.bench import fbm
from volmc.scene import load_scene


def test_upsample_interpolates_the_lattice():
    """At the lattice's own points the upsampled grid is the lattice; between two of them,
    the mean of the two (trilinear along each axis)."""
    rng = np.random.default_rng(3)
    lat = rng.random((4, 4, 4))
    up = fbm._upsample(lat, 7)        # points 0, 0.5, 1, ..., 3 of the lattice
    np.testing.assert_allclose(up[::2, ::2, ::2], lat, rtol=0, atol=1e-12)
    np.testing.assert_allclose(up[1, 0, 0], 0.5 * (lat[0, 0, 0] + lat[1, 0, 0]), atol=1e-12)
    np.testing.assert_allclose(up[1, 1, 1], lat[:2, :2, :2].mean(), atol=1e-12)


def test_clouds_are_seeded_bounded_and_loadable(tmp_path):
    """A seed gives the same grid twice and another seed another one; values in [0, 1]
    with maximum 1, empty at the box's corners, non-empty at its centre; the written scene
    loads with the grid."""
    a, b = fbm.fbm_cloud(1, 32), fbm.fbm_cloud(2, 32)
    np.testing.assert_array_equal(a, fbm.fbm_cloud(1, 32))
    assert not np.array_equal(a, b)
    for g in (a, b):
        assert g.dtype == np.float32 and g.min() == 0.0 and g.max() == 1.0
        assert g[0, 0, 0] == 0.0 and g[16, 16, 16] > 0.0
        assert 0.1 < (g > 0).mean() < 0.35
    (path,) = fbm.write_clouds(tmp_path, [5])
    scene = load_scene(path)
    assert tuple(scene.camera.resolution) == (96, 96)
    np.testing.assert_array_equal(np.load(tmp_path / "fbm5.npy"), fbm.fbm_cloud(5))


def test_bad_seeds_are_a_usage_error(tmp_path, capsys):
    for bad in ("x", "1,-2"):
        with pytest.raises(SystemExit) as e:
            fbm.main([str(tmp_path), "--seeds", bad])
        assert e.value.code == 2
        assert "--seeds" in capsys.readouterr().err
