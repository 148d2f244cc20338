"""Kernel-vs-reference, image level: OpenCL and Numba renders agree by a per-pixel z-test
(Sidak, 1 % family false-failure rate per scene) and in their means, for every shipped scene
and for variants that switch each kernel feature flag on and off."""

import tomllib

import numpy as np
import pytest

from volmc.check import check_scene, compare_images
from volmc.resources import scenes_dir
from volmc.scene import load_scene, scene_from_dict
from volmc.scene.features import FEATURES, features

SMALL = ["camera.resolution=[12, 10]"]

HOMOG = {
    "camera": {"eye": [0.4, 0.3, 3.5], "target": [0, 0, 0], "fov": 45, "resolution": [12, 10]},
    "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": 1.0, "scale": 2.0,
               "albedo": [0.9, 0.7, 0.5]},
    "lights": [{"type": "point", "position": [0.5, 1.6, 0.8], "intensity": 3.0},
               {"type": "directional", "direction": [-1, -1, -0.3], "irradiance": 1.5}],
    "render": {"spp": 256, "max_depth": 3, "rr_depth": 5},
}


def _variants(tmp_path):
    rng = np.random.default_rng(1)
    np.save(tmp_path / "g.npy", (rng.random((6, 7, 8)) ** 3).astype(np.float32))
    np.save(tmp_path / "t.npy", (600.0 + 1400.0 * rng.random((5, 4, 6))).astype(np.float32))
    grid = {"file": str(tmp_path / "g.npy")}
    return {
        "homogeneous point+directional, isotropic, no RR": scene_from_dict(HOMOG),
        "grid, orthographic, directional only, HG, unbounded depth": scene_from_dict(
            dict(HOMOG, lights=[HOMOG["lights"][1]],
                 medium=dict(HOMOG["medium"], density=grid, scale=5.0)),
            overrides=["camera.type=orthographic", "camera.size=2.5",
                       "medium.phase={type='hg', g=-0.4}", "render.max_depth=-1",
                       "render.rr_depth=2"]),
        "grid under an octree, Sobol samples, equiangular, split light samples": scene_from_dict(
            dict(HOMOG, lights=HOMOG["lights"] + [{"type": "environment", "radiance": 0.3}],
                 medium=dict(HOMOG["medium"], density=grid, scale=5.0)),
            overrides=["render.majorant=octree", "render.sampler=sobol",
                       "render.equiangular=true", "render.light_samples=2", "render.rr=albedo",
                       "render.rr_depth=1", "render.transmittance=telescoping"]),
        "grid with the global majorant": scene_from_dict(
            dict(HOMOG, medium=dict(HOMOG["medium"], density=grid, scale=5.0)),
            overrides=["render.majorant=global"]),
        "grid with environment and both delta lights": scene_from_dict(
            dict(HOMOG, lights=HOMOG["lights"] + [{"type": "environment",
                                                   "radiance": [0.2, 0.3, 0.5]}],
                 medium=dict(HOMOG["medium"], density=grid, scale=6.0,
                             phase={"type": "hg", "g": 0.7}))),
        "absorbing grid without lights (black)": scene_from_dict(
            dict(HOMOG, lights=[], medium=dict(HOMOG["medium"], density=grid, albedo=0.0))),
        "absorbing grid, environment": scene_from_dict(
            dict(HOMOG, lights=[{"type": "environment", "radiance": 1.0}],
                 medium=dict(HOMOG["medium"], density=grid, albedo=0.0, scale=4.0))),
        "max_depth 0 homogeneous": scene_from_dict(
            dict(HOMOG, lights=[{"type": "environment", "radiance": 1.0}]),
            overrides=["render.max_depth=0"]),
        "chromatic grid, environment and sun, ratio tracking": scene_from_dict(
            dict(HOMOG, lights=HOMOG["lights"] + [{"type": "environment",
                                                   "radiance": [0.2, 0.3, 0.5]}],
                 medium=dict(HOMOG["medium"], density=grid, scale=[6.0, 3.0, 1.0]))),
        "chromatic emitting grid, hero MIS, next flight": scene_from_dict(
            dict(HOMOG, medium=dict(HOMOG["medium"], density=grid, scale=[1.0, 3.0, 6.0],
                                    albedo=0.7, emission={"radiance": [0.5, 0.3, 0.1],
                                                          "field": grid})),
            overrides=["render.spectral=hero", "render.transmittance=next_flight"]),
        "chromatic grid, one channel per path, track length": scene_from_dict(
            dict(HOMOG, medium=dict(HOMOG["medium"], density=grid, scale=[2.0, 5.0, 3.0])),
            overrides=["render.spectral=channel", "render.transmittance=track_length"]),
        "emitting grid: temperature field, chromatic": scene_from_dict(
            dict(HOMOG, medium=dict(HOMOG["medium"], density=grid, scale=[5.0, 4.0, 2.0],
                                    albedo=0.5, emission={"temperature": {
                                        "file": str(tmp_path / "t.npy")}, "scale": 1e-4}))),
        "grid stored as bricks, residual ratio": scene_from_dict(
            dict(HOMOG, medium=dict(HOMOG["medium"], density=grid, scale=5.0)),
            overrides=["render.grid_storage=bricks", "render.transmittance=residual_ratio"]),
        "grid turned and mirrored by a transform, emitting, bricks, transparent": scene_from_dict(
            dict(HOMOG, medium=dict(HOMOG["medium"], density=grid, scale=5.0, albedo=0.7,
                                    emission={"radiance": [0.4, 0.3, 0.2], "field": grid},
                                    transform={"rotate": [1, 2, 0, 40.0],
                                               "scale": [1.0, -1.0, 1.2]})),
            overrides=["render.grid_storage=bricks", "render.transparent_background=true"]),
        "emitting homogeneous absorber: radiance x grid field": scene_from_dict(
            dict(HOMOG, lights=[], medium=dict(HOMOG["medium"], albedo=0.0, emission={
                "radiance": [1.0, 0.6, 0.3], "field": grid}))),
    }


def _shipped():
    out = {}
    for f in sorted(scenes_dir().glob("**/*.toml")):
        over = list(SMALL) + ["render.spp=64"]
        text = f.read_text()
        raw = tomllib.loads(text)
        for key, med in [("medium", raw.get("medium"))] + [
                (f"media.{i}", m) for i, m in enumerate(raw.get("media", []))]:
            if isinstance(med, dict) and isinstance(med.get("density"), dict) and \
                    med["density"].get("generator") in ("cloud", "plume"):
                res = min(48, med["density"]["resolution"])
                over.append(f"{key}.density.resolution={res}")
        out[f.relative_to(scenes_dir()).as_posix()] = load_scene(f, over)
    return out


def test_variants_cover_every_feature_on_and_off(tmp_path):
    sets = [features(s) for s in list(_variants(tmp_path).values()) + list(_shipped().values())]
    for flag in FEATURES:
        assert any(flag in s for s in sets), flag
        assert any(flag not in s for s in sets), flag


@pytest.mark.parametrize("name", sorted(_shipped()))
def test_shipped_scene_kernel_matches_reference(name):
    cmp, ra, rb = check_scene(_shipped()[name])
    assert cmp.passed, cmp.summary("opencl", "numba")
    # A correct scene trips no guard on either backend (no NaN/negative sample, no cut walk).
    for res in (ra, rb):
        assert res.counters["dropped"] == res.counters["capped"] == 0, res.counters
        assert res.counters["over_majorant"] == 0, res.counters


def test_variant_scenes_kernel_matches_reference(tmp_path):
    for name, scene in _variants(tmp_path).items():
        cmp, ra, rb = check_scene(scene)
        assert cmp.passed, f"{name}: {cmp.summary('opencl', 'numba')}"
        for res in (ra, rb):
            assert res.counters["dropped"] == res.counters["capped"] == 0, (name, res.counters)


def test_same_streams_give_nearly_identical_images():
    """With the same seed both backends trace the same paths: per-pixel means agree to float32
    rounding for nearly every pixel, and the lookup counters are equal (or nearly)."""
    from volmc.render import render
    scene = load_scene(scenes_dir() / "tests" / "white_furnace.toml", ["render.spp=32"])
    a = render(scene, backend="opencl", progress=False)
    b = render(scene, backend="numba", progress=False)
    close = np.isclose(a.image, b.image, rtol=1e-3, atol=1e-6)
    assert close.mean() > 0.97
    assert abs(a.counters["lookups"] - b.counters["lookups"]) <= 1e-3 * b.counters["lookups"]


def test_compare_images_detects_a_bias():
    """The check itself has power: a 2 % bias in one image of 40x40 noisy pixels is flagged."""
    rng = np.random.default_rng(0)
    n = 400
    a = rng.exponential(1.0, size=(n, 40, 40, 3))
    b = rng.exponential(1.02, size=(n, 40, 40, 3))
    va, vb = a.var(axis=0, ddof=1) / n, b.var(axis=0, ddof=1) / n
    assert not compare_images(a.mean(0), va, b.mean(0), vb).passed
    c = rng.exponential(1.0, size=(n, 40, 40, 3))
    assert compare_images(a.mean(0), va, c.mean(0), c.var(axis=0, ddof=1) / n).passed


def test_generic_build_renders_like_the_specialised_one(tmp_path):
    """A build with every feature flag on (the specialisation benchmark's baseline) takes the
    run-time branches the scene asks for: same streams, same image, for every variant."""
    from volmc.backends.opencl import OpenCLBackend
    from volmc.render import render
    for name, scene in _variants(tmp_path).items():
        spec = render(scene, backend=OpenCLBackend(scene), spp=16, progress=False)
        gen = render(scene, backend=OpenCLBackend(scene, feature_set=FEATURES), spp=16,
                     progress=False)
        assert np.allclose(spec.image, gen.image, rtol=1e-4, atol=1e-6), name
        assert spec.counters == gen.counters, name


@pytest.mark.parametrize("estimator", ["ratio", "residual_ratio", "next_flight",
                                       "track_length", "power_series", "unbiased_raymarch",
                                       "biased_raymarch"])
def test_shadow_estimator_option(estimator):
    """render.transmittance selects the shadow-ray estimator (kernel built for it): both
    backends agree, and with an unbiased estimator the white furnace still gives L."""
    from volmc.techniques import ESTIMATORS
    scene = load_scene(scenes_dir() / "tests" / "white_furnace.toml",
                       [f"render.transmittance={estimator}", "render.spp=96",
                        "camera.resolution=[8, 8]"])
    cmp, ra, rb = check_scene(scene)
    assert cmp.passed, cmp.summary("opencl", "numba")
    assert estimator in ra.techniques["transmittance"]
    if ESTIMATORS[estimator].unbiased:
        for res in (ra, rb):
            c = compare_images(res.image, res.film.variance_of_mean(),
                               np.full_like(res.image, 0.5), np.zeros_like(res.image))
            assert c.passed, (estimator, c.summary())


def test_schema_takes_shadow_estimators_from_the_registry():
    """Every registered estimator that works on grids is a valid render.transmittance; one
    exact only on homogeneous segments is rejected with the one-line error."""
    from volmc.scene import SceneError
    from volmc.techniques import ESTIMATORS
    path = scenes_dir() / "tests" / "white_furnace.toml"
    for name, est in ESTIMATORS.items():
        if est.homogeneous_only:
            with pytest.raises(SceneError, match="render.transmittance"):
                load_scene(path, [f"render.transmittance={name}"])
        else:
            assert load_scene(path, [f"render.transmittance={name}"]).render.transmittance == name


def test_global_and_grid_majorants_agree(backend):
    """Issue 5: renders with the global majorant and with a majorant grid agree by the
    per-pixel z-test (independent seeds), and the grid needs far fewer lookups."""
    from volmc.render import render
    over = ["camera.resolution=[16, 16]", "render.spp=128", "medium.density.resolution=48"]
    a = render(load_scene(scenes_dir() / "cloud.toml", over + ["render.majorant=global"]),
               backend=backend, progress=False)
    b = render(load_scene(scenes_dir() / "cloud.toml", over + ["render.majorant=grid",
                                                               "render.seed=1"]),
               backend=backend, progress=False)
    cmp = compare_images(a.image, a.film.variance_of_mean(), b.image, b.film.variance_of_mean())
    assert cmp.passed, cmp.summary("global", "grid")
    assert b.counters["lookups"] < 0.6 * a.counters["lookups"]
    assert b.counters["over_majorant"] == 0 and b.counters["capped"] == 0


def test_decomposition_tracking_same_paths_fewer_lookups(backend):
    """render.free_flight = "decomposition" makes the same decisions as delta tracking for the
    same random numbers (identical scattering counts and, up to float32 rounding, images) but
    skips the lookups the per-cell minorant already decides."""
    from volmc.render import render
    over = ["camera.resolution=[12, 12]", "render.spp=32", "medium.density.resolution=32",
            "render.majorant_resolution=[16, 16, 16]"]   # fine cells: interior minorants > 0
    a = render(load_scene(scenes_dir() / "cloud.toml", over), backend=backend, progress=False)
    b = render(load_scene(scenes_dir() / "cloud.toml", over + ["render.free_flight=decomposition"]),
               backend=backend, progress=False)
    assert a.counters["scatter_events"] == b.counters["scatter_events"]
    assert np.allclose(a.image, b.image, rtol=1e-4, atol=1e-6)
    assert b.counters["lookups"] < a.counters["lookups"]


def test_student_t_tail_matches_scipy():
    """The Welch test's tail probability, computed without scipy, against scipy's."""
    from scipy import stats
    from volmc.check import student_t_two_sided
    rng = np.random.default_rng(5)
    t = np.concatenate([rng.uniform(0, 12, 400), rng.uniform(0, 3000, 100), [0.0, 1e-9, 40.0]])
    dof = np.concatenate([rng.uniform(0.7, 800, 400), rng.uniform(1, 4, 100), [1.0, 2.0, 3.0]])
    p, q = student_t_two_sided(t, dof), 2.0 * stats.t.sf(t, dof)
    np.testing.assert_allclose(p, q, rtol=1e-7, atol=1e-300)
    np.testing.assert_allclose(student_t_two_sided(t, np.inf), 2.0 * stats.norm.sf(t),
                               rtol=1e-12)


@pytest.mark.parametrize("spp", [2, 4])
def test_compare_images_false_failure_rate_at_few_samples(spp):
    """Two renders of the same image at 2 or 4 samples per pixel: with the variances' degrees
    of freedom a comparison (the per-pixel test and the image-mean test, each at the 1 %
    level, so at most 2 % together) fails no more often than 2 % (a binomial test on 400
    comparisons, false-failure rate 1e-4), where the z-test it replaced failed in most of
    them. Samples are exponential, skewed as path-tracing samples are."""
    from scipy import stats
    rng = np.random.default_rng(spp)
    trials, shape = 400, (12, 10, 3)
    fails = z_fails = 0
    for _ in range(trials):
        a, b = rng.exponential(1.0, (2, spp) + shape)
        ma, mb = a.mean(axis=0), b.mean(axis=0)
        va, vb = a.var(axis=0, ddof=1) / spp, b.var(axis=0, ddof=1) / spp
        fails += not compare_images(ma, va, mb, vb, dof_a=spp - 1, dof_b=spp - 1).passed
        z_fails += not compare_images(ma, va, mb, vb).passed
    assert stats.binom.sf(fails - 1, trials, 0.02) > 1e-4, fails
    assert z_fails > trials // 4, z_fails


def test_compare_images_reports_a_gross_difference():
    """Images apart by thousands of standard errors: a verdict, not an exception (the
    p-value's normal quantile was taken of 1 - p / 2, which rounds to 1)."""
    shape = (6, 5, 3)
    c = compare_images(np.ones(shape), np.full(shape, 1e-8), np.zeros(shape),
                       np.full(shape, 1e-8), dof_a=15, dof_b=15)
    assert not c.passed and c.max_abs_z > 8.0 and c.frac_outside == 1.0
    same = compare_images(np.ones(shape), np.full(shape, 1e-8), np.ones(shape),
                          np.full(shape, 1e-8), dof_a=15, dof_b=15)
    assert same.passed and same.max_abs_z == 0.0


def test_compare_images_t_test_at_its_bound():
    """Power at few samples: one pixel channel just beyond the t-test's critical value (the
    Sidak level over all channels, Welch's 6 degrees of freedom of two 4-spp renders) fails
    the comparison, just within it passes; the normal bound would fail both."""
    from scipy import stats
    from volmc.check import ALPHA, sidak_level, sidak_z
    shape = (10, 8, 3)
    per = sidak_level(ALPHA, np.prod(shape))
    t_crit = stats.t.isf(per / 2.0, 6.0)
    assert t_crit > 1.5 * sidak_z(ALPHA, np.prod(shape))
    var = np.full(shape, 0.5)
    for factor, passes in ((1.01, False), (0.99, True)):
        a = np.zeros(shape)
        a[3, 4, 1] = factor * t_crit   # the difference over sqrt(0.5 + 0.5)
        c = compare_images(a, var, np.zeros(shape), var, dof_a=3, dof_b=3)
        assert (c.max_abs_z <= c.z_bound) == passes, (factor, c.summary())
