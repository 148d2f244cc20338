"""Film accumulation, variance of the mean, EXR round trip, PNG preview."""

import numpy as np
import pytest

from volmc.film import Film, read_exr, rmse, srgb_encode, tonemap, write_exr, write_png


def test_variance_of_mean_matches_numpy():
    rng = np.random.default_rng(0)
    samples = rng.exponential(size=(37, 5, 4, 4))   # RGBA
    f = Film(4, 5)
    for s in samples:
        f.sum += s
        f.sum_sq += s * s
        f.spp += 1
    assert np.allclose(f.mean(), samples[..., :3].mean(axis=0))
    assert np.allclose(f.variance_of_mean(), samples[..., :3].var(axis=0, ddof=1) / 37)
    assert np.allclose(f.alpha(), samples[..., 3].mean(axis=0))
    assert np.allclose(f.variance_of_mean(alpha=True), samples[..., 3].var(axis=0, ddof=1) / 37)
    assert np.allclose(f.rgba(), samples.mean(axis=0))


def test_variance_undefined_below_two_samples():
    f = Film(2, 2)
    f.spp = 1
    assert np.all(np.isinf(f.variance_of_mean()))


def test_exr_round_trip_exact_and_from_strided_views(tmp_path):
    rng = np.random.default_rng(1)
    big = rng.random((9, 13, 4)).astype(np.float32) * 100
    img = big[:, :, 1:]          # a non-contiguous view: the OpenEXR trap
    assert not img.flags["C_CONTIGUOUS"]
    write_exr(tmp_path / "a.exr", img, {"spp": 7, "backend": "numba", "partial": True,
                                       "render_time_s": 1.25})
    back, meta = read_exr(tmp_path / "a.exr")
    assert back.dtype == np.float32 and np.array_equal(back, img)
    assert meta["spp"] == 7 and meta["backend"] == "numba" and meta["partial"] == 1
    assert meta["render_time_s"] == pytest.approx(1.25)
    # Channels are not swapped and rows are not flipped.
    t = np.zeros((3, 2, 3), np.float32)
    t[0, 1, 0] = 1.0
    t[2, 0, 2] = 2.0
    write_exr(tmp_path / "b.exr", t)
    back, _ = read_exr(tmp_path / "b.exr")
    assert back[0, 1, 0] == 1.0 and back[2, 0, 2] == 2.0 and back.sum() == 3.0
    # RGBA, from a strided view too; an RGB file reads with A = 1.
    write_exr(tmp_path / "c.exr", big[:, 1:, :])
    back, _ = read_exr(tmp_path / "c.exr", alpha=True)
    assert np.array_equal(back, big[:, 1:, :])
    back, _ = read_exr(tmp_path / "b.exr", alpha=True)
    assert np.array_equal(back[..., :3], t) and np.all(back[..., 3] == 1.0)


def test_srgb_and_tonemap():
    assert srgb_encode(np.array([0.0]))[0] == 0.0
    assert srgb_encode(np.array([1.0]))[0] == pytest.approx(1.0)
    assert srgb_encode(np.array([0.18]))[0] == pytest.approx(0.4614, abs=1e-3)
    x = np.linspace(0, 50, 101)[:, None, None] * np.ones((1, 1, 3))
    y = tonemap(x)
    assert np.all(np.diff(y[:, 0, 0]) >= 0) and y.max() <= 1.0 and y.min() == 0.0
    assert tonemap(np.array([[[0.25, 0.25, 0.25]]]), exposure=1, operator="clamp")[0, 0, 0] == \
        pytest.approx(srgb_encode(np.array([0.5]))[0])
    assert np.all(tonemap(np.array([[[np.nan, np.inf, -1.0]]])) == 0.0)


def test_png_written(tmp_path):
    from matplotlib import image as mpimg
    img = np.zeros((4, 6, 3))
    img[0, :, 0] = 1.0
    write_png(tmp_path / "p.png", img, operator="clamp")
    back = mpimg.imread(tmp_path / "p.png")
    assert back.shape[:2] == (4, 6)
    assert back[0, 0, 0] == pytest.approx(1.0) and back[3, 0, 0] == 0.0
    # With a coverage: RGBA, the colour un-premultiplied (straight alpha, as PNG has it).
    a = np.full((4, 6), 0.5)
    a[1] = 0.0
    write_png(tmp_path / "q.png", img * 0.5, operator="clamp", alpha=a)
    back = mpimg.imread(tmp_path / "q.png")
    assert back.shape == (4, 6, 4)
    assert back[0, 0, 0] == pytest.approx(1.0) and back[0, 0, 3] == pytest.approx(128 / 255)
    assert back[1, 0, 3] == 0.0 and back[1, 0, 0] == 0.0


def test_rmse():
    assert rmse(np.ones((2, 2, 3)), np.zeros((2, 2, 3))) == 1.0


def test_batch_schedule_is_fixed_and_complete():
    from volmc.render import BATCH_SAMPLES, batch_schedule
    s = batch_schedule(100, 1000)
    assert sum(s) == 1000 and s[:4] == [1, 2, 4, 8]
    assert max(s) <= BATCH_SAMPLES // 100
    assert batch_schedule(10**6, 5) == [1, 1, 1, 1, 1]
    assert batch_schedule(100, 1000) == s      # depends on nothing but its arguments


@pytest.mark.parametrize("n_samples", [1, 2, 7])
def test_launch_accumulation_is_float64_in_sample_order(n_samples):
    """The OpenCL backend's per-launch sums equal a plain float64 loop over the samples in
    order, bit for bit (so a pixel's sums do not depend on how the launch was cut), and
    differ from float32 arithmetic; the pad channels beyond ``channels`` are not summed."""
    from volmc.backends.opencl import accumulate_samples
    rng = np.random.default_rng(7)
    x = (rng.random((5, n_samples, 8)) * 10.0 ** rng.integers(-8, 8, (5, n_samples, 8)))
    x = x.astype(np.float32)
    total, total_sq = accumulate_samples(x, 7)
    want = np.zeros((5, 7))
    want_sq = np.zeros((5, 7))
    for k in range(n_samples):
        v = x[:, k, :7].astype(np.float64)
        want = want + v
        want_sq = want_sq + v * v
    assert total.dtype == total_sq.dtype == np.float64
    assert np.array_equal(total, want) and np.array_equal(total_sq, want_sq)
    assert total.shape == (5, 7)
    if n_samples > 1:
        f32 = x[:, :, :7].sum(axis=1, dtype=np.float32)
        assert not np.array_equal(total, f32.astype(np.float64))
