"""render.mis: the balance and power heuristics where light and phase sampling combine (the
environment). Each pair of weights sums to 1, so either heuristic is unbiased: the white
furnace stays exact, and the two heuristics render the same image within the noise
(z-tests with a Sidak bound, family false-failure rate ALPHA = 1 %)."""

import numpy as np
import pytest

from stats import ALPHA, z_bound
from volmc.check import ROUNDING_REL
from volmc.constants import MIS_BALANCE, MIS_POWER
from volmc.reference.sampling import mis_balance, mis_power, mis_weight
from volmc.render import render
from volmc.resources import scenes_dir
from volmc.scene import load_scene

FURNACE = scenes_dir() / "tests" / "white_furnace.toml"


def test_weights_of_a_pair_sum_to_one():
    rng = np.random.default_rng(3)
    for a, b in rng.random((1000, 2)) * np.array([10.0, 0.1]) + 1e-6:
        for kind in (MIS_BALANCE, MIS_POWER):
            assert mis_weight(kind, a, b) + mis_weight(kind, b, a) == pytest.approx(1.0,
                                                                                    rel=1e-12)
        # The power heuristic leans harder on the strategy with the larger pdf.
        assert mis_power(a, b) >= mis_balance(a, b) if a > b else mis_power(a, b) <= \
            mis_balance(a, b)
    assert mis_power(3.0, 4.0) == pytest.approx(9.0 / 25.0)


@pytest.mark.parametrize("key", ["render.mis=power", "render.light_samples=3"])
def test_white_furnace_stays_exact(backend, key):
    """The power heuristic, and splitting with the sample counts in the balance heuristic's
    weights (N p_light against p_phase), keep the white furnace exact: every pixel channel
    and the image mean of each channel against 0.5 (z-tests with the render's variances of
    the mean, the means' from the sum of the independent pixels' variances; Sidak over all
    of them). One pixel's noise hides a bias the image mean does not: swapped light and
    phase pdfs in the environment's weight gave 0.677 within the per-pixel bounds."""
    scene = load_scene(FURNACE, [key, "render.spp=256",
                                 "camera.resolution=[8, 8]", "medium.phase.g=0.9",
                                 "render.rr_depth=1000000"])
    res = render(scene, progress=False, backend=backend)
    m, var = res.film.mean()[..., :3], res.film.variance_of_mean()[..., :3]
    # Float32 rounding where a pixel is exact (zero variance).
    var = var + (ROUNDING_REL * 0.5) ** 2
    z = (m - 0.5) / np.sqrt(var)
    n_pix = m.shape[0] * m.shape[1]
    z_mean = (m.mean(axis=(0, 1)) - 0.5) / (np.sqrt(var.sum(axis=(0, 1))) / n_pix)
    bound = z_bound(ALPHA, z.size + z_mean.size)
    assert np.abs(z).max() < bound, np.abs(z).max()
    assert np.abs(z_mean).max() < bound, (m.mean(axis=(0, 1)), z_mean)


def test_power_and_balance_agree(backend):
    keys = ["render.spp=512", "camera.resolution=[8, 8]", "medium.phase.g=0.8",
            "medium.albedo=[0.9, 0.7, 0.5]", "render.max_depth=6"]
    a = render(load_scene(FURNACE, keys + ["render.mis=power"]), progress=False,
               backend=backend)
    b = render(load_scene(FURNACE, keys + ["render.mis=balance", "render.seed=9"]),
               progress=False, backend=backend)
    d = a.film.mean() - b.film.mean()
    se = np.sqrt(a.film.variance_of_mean() + b.film.variance_of_mean())
    assert np.abs(d / se).max() < z_bound(ALPHA, d.size)


def test_bad_mis_key():
    from volmc.scene.errors import SceneError
    with pytest.raises(SceneError, match="render.mis"):
        load_scene(FURNACE, ["render.mis=veach"])
