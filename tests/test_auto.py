"""render.transmittance = "auto" (volmc/reference/tracking.py ``auto_segment_technique``,
volmc/reference/estimators.py ``transmittance_auto`` and ``transmittance_auto_shadow``, and
their kernel twins): the rule's choices on constructed segments, unbiasedness of both
variants, the kernel-reference match, and renders."""

import functools
import math

import numpy as np
import pytest

from render_pairs import assert_estimators_render_alike
from stats import ALPHA, z_bound
from volmc.bench.transmittance import SHAPES, profile_case
from volmc.bench.transmittance_runner import estimator
from volmc.constants import (AUTO_THIN_DEPTH, DENSITY_RAMP, TRACK_LENGTH,
                             TRACK_RESIDUAL_RATIO)
from volmc.reference import medium as X
from volmc.reference.tracking import auto_segment_technique
from volmc.resources import default_scene
from volmc.scene import load_scene

RAY = np.array([[0, 0, 0, 1, 0, 0, 0, 1, 0]], np.float64)
NO_GRID = np.zeros((1, 1, 1))
CASES = [(shape, T, k) for shape in SHAPES for T in (0.05, 0.5, 0.95) for k in (0.2, 1.0)]


@functools.lru_cache(maxsize=None)
def _runner(backend, name, shadow=False, chromatic=False):
    return estimator(backend, name, chromatic=chromatic, shadow=shadow)


def test_rule_on_constructed_segments():
    """Residual ratio tracking up to AUTO_THIN_DEPTH mean free paths of majorant-minorant
    gap, track length beyond, whatever the bounds and length that make the gap."""
    th = AUTO_THIN_DEPTH
    for s_maj, s_min, L, want in [
            (th / 2, 0.0, 1.0, TRACK_RESIDUAL_RATIO),
            (th, 0.0, 1.0, TRACK_RESIDUAL_RATIO),          # the threshold itself is thin
            (1.01 * th, 0.0, 1.0, TRACK_LENGTH),
            (100.0, 100.0 - th / 2, 1.0, TRACK_RESIDUAL_RATIO),   # dense but tightly bounded
            (100.0, 99.0, 1.0, TRACK_LENGTH if th < 1 else TRACK_RESIDUAL_RATIO),
            (1e4, 0.0, 0.5 * th / 1e4, TRACK_RESIDUAL_RATIO),     # short
            (1e4, 0.0, 2.0 * th / 1e4, TRACK_LENGTH),
            (0.5, 0.25, 1000.0 * th, TRACK_LENGTH)]:               # long and thin
        assert auto_segment_technique(s_maj, s_min, L) == want, (s_maj, s_min, L)


def _profile(mbar, mu_c):
    """A ramp on [0, 1] with extinction between 0.5 and 2.5 and bounds (mbar, mu_c)."""
    return X.make_profile(DENSITY_RAMP, 0.5, 2.0, 0.0, 1.0, 1.0), np.array([[mbar, mu_c]])


@pytest.mark.parametrize("backend", ["numba", "opencl"])
def test_shadow_variant_runs_the_chosen_technique(backend):
    """On a one-segment ray auto's shadow variant makes exactly the estimates (same random
    numbers) of the technique the rule names: residual ratio tracking on a segment whose gap
    is at most the threshold, track length on a thicker one."""
    for mbar, mu_c, same_as in [(2.5 + 0.5 * AUTO_THIN_DEPTH, 2.5, "residual_ratio"),
                                (2.6, 0.5, "track_length")]:
        med, bounds = _profile(mbar, mu_c)
        assert (auto_segment_technique(mbar, mu_c, 1.0) == TRACK_RESIDUAL_RATIO) == \
            (same_as == "residual_ratio")
        a, ca = _runner(backend, "auto", shadow=True).run(med, NO_GRID, RAY, bounds, 2000, 3)
        b, cb = _runner(backend, same_as).run(med, NO_GRID, RAY, bounds, 2000, 3)
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(ca, cb)


@pytest.mark.parametrize("backend", ["numba", "opencl"])
def test_alone_variant_runs_ray_marching_or_telescoping(backend):
    """Where the transmittance is the whole estimate, auto is unbiased ray marching in a grey
    medium and telescoping in a colour-dependent one: the same estimates, bit for bit."""
    med, bounds = _profile(2.6, 0.5)
    a, _ = _runner(backend, "auto").run(med, NO_GRID, RAY, bounds, 2000, 3)
    b, _ = _runner(backend, "unbiased_raymarch").run(med, NO_GRID, RAY, bounds, 2000, 3)
    np.testing.assert_array_equal(a, b)
    col = med.copy()
    col["chroma"] = (1.0, 0.5, 0.25)
    col["spectral"] = 1   # any mode but SPECTRAL_GREY: the medium is colour-dependent
    a, _ = _runner(backend, "auto", chromatic=True).run(col, NO_GRID, RAY, bounds, 2000, 3)
    b, _ = _runner(backend, "telescoping", chromatic=True).run(col, NO_GRID, RAY, bounds,
                                                                2000, 3)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("backend", ["numba", "opencl"])
def test_shadow_variant_unbiased_on_every_profile(backend):
    """Mean within the Sidak bound of exp(-tau) on every profile, three transmittances, two
    majorant tightnesses (so both techniques are chosen)."""
    bound = z_bound(ALPHA, len(CASES))
    chosen = set()
    for shape, T, k in CASES:
        med, mbar, mu_c, exact, _ = profile_case(shape, T, k)
        chosen.add(auto_segment_technique(mbar, mu_c, 1.0))
        est, _ = _runner(backend, "auto", shadow=True).run(med, NO_GRID, RAY,
                                                           np.array([[mbar, mu_c]]), 8000, 5)
        se = est.std(ddof=1) / math.sqrt(est.size)
        tol = 3e-6 if backend == "opencl" else 1e-12
        if se == 0:
            assert abs(est.mean() - exact) <= tol, (shape, T, k)
        else:
            z = (est.mean() - exact) / math.sqrt(se * se + tol * tol)
            assert abs(z) < bound, f"{shape} T={T} k={k}: mean {est.mean():.5f} vs {exact:.5f}"
    assert chosen == {TRACK_LENGTH, TRACK_RESIDUAL_RATIO}


@functools.lru_cache(maxsize=None)
def _cloud():
    """Camera and shadow segments recorded from a small render of the cloud (32^3), with the
    medium record, grid and majorant grid the render traced them through."""
    from volmc.bench.segments import record_segments
    from volmc.bench.transmittance import replay_cases
    scene = load_scene(default_scene(), ["medium.density.resolution=32",
                                         "camera.resolution=[16, 16]"])
    rec = record_segments(scene, "opencl", per_pixel=8)
    return rec, replay_cases(rec, 48, seed=1)


def _run_grid(backend, shadow, rec, rays, n):
    """auto on ``rays`` through the recording's own majorant grid (not one global bound)."""
    return _runner(backend, "auto", shadow=shadow).run(rec.medium, rec.grid, rays, None, n, 9,
                                                       maj=rec.maj, mnr=rec.mnr)


@pytest.mark.parametrize("backend", ["numba", "opencl"])
@pytest.mark.parametrize("shadow", [False, True])
def test_unbiased_on_cloud_rays_with_a_majorant_grid(backend, shadow):
    """Camera and shadow rays through the cloud's majorant grid (segments thin and thick, so
    the rule picks both techniques): mean error within the Sidak bound."""
    rec, sets = _cloud()
    bound = z_bound(ALPHA, len(sets))
    for label, rays, exact in sets:
        est, cnt = _run_grid(backend, shadow, rec, rays, 256)
        err = est.reshape(len(rays), -1) - exact[:, None]
        se = err.std(ddof=1) / math.sqrt(err.size)
        assert abs(err.mean()) < bound * se + 1e-6, (label, err.mean(), se)
        assert cnt[:, 2].sum() == 0


@pytest.mark.parametrize("shadow", [False, True])
def test_kernel_matches_reference_on_a_majorant_grid(shadow):
    """Same rays and streams through the majorant grid: per-estimate agreement for the vast
    majority, equal means."""
    rec, sets = _cloud()
    label, rays, exact = sets[1]
    a, ca = _run_grid("numba", shadow, rec, rays, 128)
    b, cb = _run_grid("opencl", shadow, rec, rays, 128)
    same = np.isclose(a, b, rtol=1e-3, atol=1e-5) & (ca[:, 0] == cb[:, 0])
    assert same.mean() > 0.99, same.mean()
    se = math.sqrt(a.var() / a.size + b.var() / b.size)
    assert abs(a.mean() - b.mean()) <= z_bound(ALPHA) * se + 1e-6


@pytest.mark.parametrize("backend", ["numba", "opencl"])
def test_render_equals_ratio_tracking(backend):
    """The cloud rendered with auto (shadow rays: the rule's mix) equals ratio tracking's
    render: per-pixel and image-mean two-sample z-tests."""
    assert_estimators_render_alike(backend, "auto")


@pytest.mark.parametrize("backend", ["numba", "opencl"])
def test_view_rays_use_residual_ratio_tracking(backend):
    """A render that cannot scatter (albedo 0: each pixel is the environment times the
    camera ray's transmittance) runs auto's estimator for camera rays, residual ratio
    tracking, not the shadow-ray mix: the same image bit for bit, and lookups differing from
    the mix's."""
    from volmc.render import render
    keys = ["medium.density.resolution=16", "camera.resolution=[6, 6]", "render.spp=64",
            "medium.albedo=0"]
    a = render(load_scene(default_scene(), keys + ["render.transmittance=auto"]),
               progress=False, backend=backend)
    b = render(load_scene(default_scene(), keys + ["render.transmittance=residual_ratio"]),
               progress=False, backend=backend)
    c = render(load_scene(default_scene(), keys + ["render.transmittance=track_length"]),
               progress=False, backend=backend)
    assert a.counters["lookups"] == b.counters["lookups"]
    assert a.counters["lookups"] != c.counters["lookups"]
    np.testing.assert_array_equal(a.image, b.image)
