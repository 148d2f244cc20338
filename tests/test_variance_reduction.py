"""Variance-reduction switches: equiangular sampling (render.equiangular), splitting
(render.light_samples) and the Russian-roulette rule (render.rr).

Each switch changes how an integral is estimated, never its value: a render with the switch
on equals one with it off within the noise (two-sample z-tests per pixel and channel, Sidak
bound, family false-failure rate ALPHA = 1 % per test), on both backends, in homogeneous and
grid media, grey and chromatic. The point light of these scenes is outside the medium, so
next-event estimation without equiangular sampling has finite variance and the z-test's
normal approximation holds.
"""

import math

import numpy as np
import pytest
from numba import njit
from scipy import integrate

from cl_harness import out_buf, run, to_dev
from stats import ALPHA, chi2_pvalue, z_bound
from volmc.reference.rng import uniforms
from volmc.reference.sampling import (equiangular_pdf, invert_equiangular_sample,
                                      sample_equiangular)
from volmc.render import render
from volmc.resources import scenes_dir
from volmc.scene import load_scene

TESTS = scenes_dir() / "tests"
GRID = TESTS / "constant_grid.toml"
HOMOGENEOUS = TESTS / "constant_grid_homogeneous.toml"
ROULETTE = TESTS / "roulette.toml"
SMALL = ["camera.resolution=[8, 8]"]
#: (h, D, ta, tb): the point's foot and distance, the interval; foot inside, before, after.
EQ_CASES = ((0.3, 0.2, -1.0, 2.0), (-2.0, 0.05, 0.0, 1.5), (5.0, 3.0, 0.0, 1.0),
            (0.0, 1e-3, -1.0, 1.0),
            # a point nearly on the ray's line (a lamp at the camera's pinhole), behind the
            # interval and beyond it: D is a rounding error of float32, then of float64
            (-3.0, 4e-7, 0.0, 2.0), (5.0, 4e-7, 0.0, 2.0), (-3.0, 4e-16, 0.0, 2.0))
#: A path segment of 5e-7 units seen from 1.4 units: in float32 its two angles are equal.
TINY = (-1.37842, 0.153539, 0.0, 5.02335e-07)


def _agree(a, b):
    """Max |z| of the per-pixel difference of two renders, and the Sidak bound."""
    d = a.film.mean() - b.film.mean()
    se = np.sqrt(a.film.variance_of_mean() + b.film.variance_of_mean())
    z = d / np.where(se > 0, se, np.inf)
    return np.abs(z).max(), z_bound(ALPHA, d.size)


def _render(path, keys, backend):
    return render(load_scene(path, SMALL + keys), progress=False, backend=backend)


# --- the equiangular sampler ----------------------------------------------------------------

@njit(cache=True)
def _eq_samples(u, h, D, ta, tb):
    out = np.empty((u.shape[0], 2))
    for i in range(u.shape[0]):
        out[i, 0], out[i, 1] = sample_equiangular(u[i], h, D, ta, tb)
    return out


@pytest.mark.parametrize("h,D,ta,tb", EQ_CASES)
def test_equiangular_pdf_integrates_to_one_and_matches_samples(h, D, ta, tb):
    total = integrate.quad(lambda t: equiangular_pdf(t, h, D, ta, tb), ta, tb,
                           points=[h] if ta < h < tb else None, limit=400)[0]
    assert total == pytest.approx(1.0, abs=1e-7)
    s = _eq_samples(uniforms(7, 0, 0, 2, 100_000), h, D, ta, tb)
    assert s[:, 0].min() >= ta and s[:, 0].max() <= tb
    assert np.allclose(s[:, 1], [equiangular_pdf(t, h, D, ta, tb) for t in s[:, 0]])
    # chi-square against the pdf integrated over 40 equal-probability bins
    edges = [sample_equiangular(k / 40, h, D, ta, tb)[0] for k in range(41)]
    edges[0], edges[-1] = ta, tb
    obs = np.histogram(s[:, 0], bins=edges)[0]
    exp = [integrate.quad(lambda t: equiangular_pdf(t, h, D, ta, tb), a, b)[0] * len(s)
           for a, b in zip(edges[:-1], edges[1:])]
    assert chi2_pvalue(obs, exp)[0] > ALPHA


@pytest.mark.parametrize("h,D,ta,tb", EQ_CASES)
def test_equiangular_inverse_round_trip(h, D, ta, tb):
    u = uniforms(8, 0, 0, 2, 2000)
    back = np.array([invert_equiangular_sample(sample_equiangular(x, h, D, ta, tb)[0], h, D,
                                               ta, tb) for x in u])
    assert np.allclose(back, u, atol=1e-9)


def test_equiangular_kernel_matches_the_reference(lanes):
    u = uniforms(9, 0, 0, 2, 4000).astype(np.float32)
    for h, D, ta, tb in EQ_CASES:
        out, ob = out_buf((u.size, 3))
        run("t_equiangular", u.size, to_dev(u), np.float32(h), np.float32(D), np.float32(ta),
            np.float32(tb), ob, outs=[(out, ob)])
        f = [float(np.float32(x)) for x in (h, D, ta, tb)]
        ref = np.array([(*sample_equiangular(float(x), *f),
                         invert_equiangular_sample(sample_equiangular(float(x), *f)[0], *f))
                        for x in u])
        assert np.allclose(out[:, 0], ref[:, 0], rtol=1e-5, atol=1e-5 * (tb - ta))
        assert np.allclose(out[:, 1], ref[:, 1], rtol=2e-4)
        assert np.allclose(out[:, 2], u, atol=2e-4)


# --- equiangular sampling in renders --------------------------------------------------------

@pytest.mark.parametrize("path,extra", [
    (HOMOGENEOUS, []),                                      # MIS with free flight
    (HOMOGENEOUS, ["render.mis=power"]),
    (GRID, []),                                             # equiangular alone, grid
    (GRID, ['medium.density={file="data/ramp8.npy"}', "medium.scale=[3.0, 2.0, 1.0]"]),
])
def test_equiangular_renders_the_same_image(backend, path, extra):
    keys = ["render.spp=384", "render.max_depth=3"] + extra
    a = _render(path, keys + ["render.equiangular=true"], backend)
    b = _render(path, keys + ["render.equiangular=false", "render.seed=5"], backend)
    z, bound = _agree(a, b)
    assert z < bound


#: The point light at the camera's pinhole ("flash"): every camera ray passes through it.
FLASH = "lights.2.position=[2.4, 1.9, 3.0]"


@pytest.mark.parametrize("path,depth,extra", [
    (GRID, 1, []), (HOMOGENEOUS, 1, []), (HOMOGENEOUS, 3, ["render.mis=power"]),
    (HOMOGENEOUS, 3, ["medium.scale=4.0"]), (GRID, 1, [FLASH]), (HOMOGENEOUS, 1, [FLASH])])
def test_equiangular_with_only_the_point_light(backend, path, depth, extra):
    """Only the point light shining: in the grid (max_depth = 1) the image is the
    equiangular estimate alone, in the homogeneous medium the MIS combination, and either
    must equal next-event estimation's. Also with the light at the camera's pinhole, where
    the light's distance from each camera ray's line is a rounding error (found by an
    outside check against Mitsuba: +21 % in the kernels, +1.8 % in the reference)."""
    keys = ["render.spp=512", f"render.max_depth={depth}", "lights.0.radiance=0",
            "lights.1.irradiance=0"] + extra
    a = _render(path, keys + ["render.equiangular=true"], backend)
    b = _render(path, keys + ["render.seed=3"], backend)
    z, bound = _agree(a, b)
    assert z < bound
    assert np.all(np.isfinite(a.film.mean()))
    assert a.counters["dropped"] == 0


def test_equiangular_lowers_variance_near_a_lamp_in_fog():
    """The point of the technique: a lamp inside a homogeneous medium. Next-event estimation
    from distance-sampled vertices has unbounded 1/r^2; with equiangular sampling the
    variance of the image falls by far more than the sampling noise of the comparison."""
    keys = ["camera.resolution=[16, 12]", "render.spp=64", "render.max_depth=1"]
    fog = scenes_dir() / "gallery" / "fog.toml"
    on = render(load_scene(fog, keys + ["render.equiangular=true"]), progress=False,
                backend="numba")
    off = render(load_scene(fog, keys + ["render.equiangular=false"]), progress=False,
                 backend="numba")
    assert off.film.variance_of_mean().mean() > 4 * on.film.variance_of_mean().mean()


# --- splitting and the roulette rule -------------------------------------------------------

@pytest.mark.parametrize("mis", ["balance", "power"])
def test_light_samples_render_the_same_image(backend, mis):
    keys = ["render.spp=256", "render.max_depth=4", f"render.mis={mis}"]
    a = _render(GRID, keys + ["render.light_samples=4"], backend)
    b = _render(GRID, keys + ["render.seed=21"], backend)
    z, bound = _agree(a, b)
    assert z < bound
    # four shadow rays per light and vertex instead of one
    assert a.counters["shadow_rays"] > 3 * b.counters["shadow_rays"] * \
        a.counters["scatter_events"] / b.counters["scatter_events"]


@pytest.mark.parametrize("path,keys", [
    (ROULETTE, ["medium.albedo=[0.9, 0.7, 0.5]", "render.spp=256"]),
    (GRID, ["render.spp=256", "render.rr_depth=1", "render.max_depth=-1"]),
])
def test_albedo_roulette_is_unbiased(backend, path, keys):
    a = render(load_scene(path, keys + ["render.rr=albedo"]), progress=False,
               backend=backend)
    b = render(load_scene(path, keys + ["render.seed=77"]), progress=False, backend=backend)
    z, bound = _agree(a, b)
    assert z < bound
    # the albedo rule ends paths earlier when the albedo is below 1
    assert a.counters["scatter_events"] < b.counters["scatter_events"]


def test_roulette_survival_probabilities():
    from volmc.constants import RR_ALBEDO, RR_MAX_SURVIVAL, RR_THROUGHPUT
    from volmc.params import params_dtype
    from volmc.reference.integrator import survival_probability
    prm = np.zeros(1, params_dtype())
    for rule, want in ((RR_THROUGHPUT, 0.5), (RR_ALBEDO, 0.25)):
        prm[0]["rr"] = rule
        assert survival_probability(prm[0], (0.5, 0.2, 0.1), (0.5, 0.5, 0.9)) == want
    prm[0]["rr"] = RR_THROUGHPUT
    # The cap: 1 under a depth bound, RR_MAX_SURVIVAL without one.
    for depth, cap in ((64, 1.0), (0, 1.0), (-1, RR_MAX_SURVIVAL)):
        prm[0]["max_depth"] = depth
        assert survival_probability(prm[0], (8.0, 0.0, 0.0), (1.0, 1.0, 1.0)) == cap
        assert survival_probability(prm[0], (0.97, 0.0, 0.0), (1.0, 1.0, 1.0)) == min(0.97, cap)


@pytest.mark.parametrize("key,value", [("light_samples", "0"), ("light_samples", "2.5"),
                                       ("equiangular", "1"), ("rr", "luminance")])
def test_bad_keys(key, value):
    from volmc.scene.errors import SceneError
    with pytest.raises(SceneError, match=f"render.{key}"):
        load_scene(GRID, [f"render.{key}={value}"])


def test_equiangular_modes():
    """Which estimator covers point lights: MIS only where free flight's pdf is known."""
    from volmc.pack import pack_scene as pack
    from volmc.reference.integrator import (EQUIANGULAR_ALONE, EQUIANGULAR_MIS,
                                            EQUIANGULAR_OFF, equiangular_mode)
    from volmc.reference.medium import media_data
    for path, keys, want in ((HOMOGENEOUS, [], EQUIANGULAR_MIS),
                             (HOMOGENEOUS, ["medium.scale=[1.0, 2.0, 3.0]"], EQUIANGULAR_ALONE),
                             (GRID, [], EQUIANGULAR_ALONE)):
        pk = pack(load_scene(path, keys + ["render.equiangular=true"]))
        assert equiangular_mode(pk.params[0], media_data(pk)) == want
    pk = pack(load_scene(GRID, []))
    assert equiangular_mode(pk.params[0], media_data(pk)) == EQUIANGULAR_OFF
    assert math.isfinite(equiangular_pdf(0.5, 0.5, 1e-30, 0.0, 1.0))


def test_equiangular_on_a_segment_too_short_for_its_angles(lanes):
    """Found by `volmc bench variance` (3 dropped samples in the lamp in fog): a free flight
    that ends 5e-7 units before the box face leaves a segment whose two angles are equal in
    float32, and the equiangular pdf was D / (0 x ...) = inf, its MIS weight NaN. Such a
    segment is sampled uniformly, in both backends and in the pdf the MIS weight reads."""
    h, D, ta, tb = TINY
    u = np.array([0.0, 0.25, 0.784123, 1 - 2.0**-24], np.float32)
    out, ob = out_buf((u.size, 3))
    run("t_equiangular", u.size, to_dev(u), *[np.float32(x) for x in TINY], ob,
        outs=[(out, ob)])
    assert np.all(np.isfinite(out)) and np.all(out[:, 1] > 0)
    assert np.allclose(out[:, 1], 1.0 / np.float32(tb), rtol=1e-5)
    assert np.all((out[:, 0] >= ta) & (out[:, 0] <= tb))
    assert np.allclose(out[:, 2], u, atol=1e-6)
    # the reference switches the same way when float64 angles are equal too
    # (seen from 1e8 units, a unit segment's angles differ by 1e-16: equal in float64)
    t, pdf = sample_equiangular(0.5, 0.0, 1.0, 1e8, 1e8 + 1.0)
    assert t == 1e8 + 0.5 and pdf == 1.0 == equiangular_pdf(t, 0.0, 1.0, 1e8, 1e8 + 1.0)
    assert invert_equiangular_sample(t, 0.0, 1.0, 1e8, 1e8 + 1.0) == 0.5
    assert sample_equiangular(0.5, 0.0, 1.0, 0.3, 0.3)[1] == 0.0
    scene = load_scene(scenes_dir() / "gallery" / "fog.toml",
                       ["camera.resolution=[128,128]", "render.spp=256", "render.seed=1",
                        "render.equiangular=true"])
    assert render(scene, progress=False, backend="opencl").counters["dropped"] == 0
