"""Transmittance estimators (volmc/reference/estimators.py and kernels/estimators.h) against
exact answers, on both backends, plus their lookup counts and the kernel-reference match."""

import functools
import math

import numpy as np
import pytest

from stats import ALPHA, z_bound
from volmc.bench.segments import record_segments
from volmc.bench.transmittance import SHAPES, profile_case, replay_cases
from volmc.bench.transmittance_runner import OpenCLEstimator, run_numba
from volmc.techniques import ESTIMATORS
from volmc.reference import medium as X

UNBIASED = [n for n, e in ESTIMATORS.items() if e.unbiased and not e.homogeneous_only]
RAY = np.array([[0, 0, 0, 1, 0, 0, 0, 1, 0]], np.float64)
CASES = [(shape, T, k) for shape in SHAPES for T in (0.05, 0.5, 0.95) for k in (0.2, 1.0)]


@functools.lru_cache(maxsize=None)
def _ocl(name):
    return OpenCLEstimator(name)


def _run(backend, name, med, grid, rays, bounds, n, seed=5):
    if backend == "numba":
        return run_numba(name, med, grid, rays, bounds, n, seed)
    return _ocl(name).run(med, grid, rays, bounds, n, seed)


@pytest.mark.parametrize("name", UNBIASED)
def test_unbiased_on_every_profile(backend, name):
    """Mean within the Sidak bound (about 4 s.e.) of exp(-tau) on every 1-D profile, at
    three transmittances and two majorant tightnesses."""
    bound = z_bound(ALPHA, len(CASES))
    for shape, T, k in CASES:
        med, mbar, mu_c, exact, _ = profile_case(shape, T, k)
        est, _ = _run(backend, name, med, np.zeros((1, 1, 1)), RAY, np.array([[mbar, mu_c]]),
                      8000)
        se = est.std(ddof=1) / math.sqrt(est.size)
        tol = 3e-6 if backend == "opencl" else 1e-12   # float32 evaluation of exact cases
        if se == 0:
            assert abs(est.mean() - exact) <= tol, (shape, T, k)
        else:
            z = (est.mean() - exact) / math.sqrt(se * se + tol * tol)
            assert abs(z) < bound, f"{shape} T={T} k={k}: mean {est.mean():.5f} vs {exact:.5f}"


@functools.lru_cache(maxsize=None)
def _cloud_rays():
    """48 camera and 48 shadow segments recorded from a small render of the cloud (packed
    frame), the medium record and grid they were traced through, and the global majorant."""
    from volmc.resources import default_scene
    from volmc.scene import load_scene
    scene = load_scene(default_scene(), ["medium.density.resolution=32",
                                         "camera.resolution=[16, 16]"])
    rec = record_segments(scene, "opencl", per_pixel=8)
    mbar = float(rec.medium[0]["scale"]) * float(rec.grid.max())
    return rec, mbar, replay_cases(rec, 48, seed=1)


@pytest.mark.parametrize("name", UNBIASED)
def test_unbiased_on_grid_rays(backend, name):
    """Recorded camera and shadow segments of the cloud under its global majorant: the mean
    error over all segments and estimates is within the bound, against the exact optical
    depth of each."""
    rec, mbar, sets = _cloud_rays()
    bound = z_bound(ALPHA, len(sets))
    for label, rays, exact in sets:
        bounds = np.tile([mbar, 0.0], (len(rays), 1))
        est, cnt = _run(backend, name, rec.medium, rec.grid, rays, bounds, 256)
        err = est.reshape(len(rays), -1) - exact[:, None]
        se = err.std(ddof=1) / math.sqrt(err.size)
        assert abs(err.mean()) < bound * se + 1e-6, (label, err.mean(), se)
        assert cnt[:, 2].sum() == 0   # never capped


def test_analytic_is_exact_on_homogeneous_segments():
    for T in (0.01, 0.5, 0.99):
        med, _, _, exact, _ = profile_case("constant", T, 1.0)
        mu = float(med["density"])  # the analytic estimator is given the extinction itself
        for backend in ("numba", "opencl"):
            est, cnt = _run(backend, "analytic", med, np.zeros((1, 1, 1)), RAY,
                            np.array([[mu, mu]]), 16)
            assert np.allclose(est, exact, rtol=1e-6) and cnt[:, 0].sum() == 0


def test_lookup_counts():
    """Ratio and next-flight tracking: Poisson(mbar L) lookups; residual ratio: Poisson((mbar -
    mu_c) L); biased ray marching: ceil(mbar L); track length: at most ratio tracking's."""
    med = X.make_profile(X.DENSITY_RAMP, 1.0, 3.0, L=1.0)
    mbar, mu_c, n = 6.0, 1.0, 40000
    bounds = np.array([[mbar, mu_c]])
    g = np.zeros((1, 1, 1))
    for name, expect in (("ratio", mbar), ("next_flight", mbar), ("residual_ratio", mbar - mu_c)):
        _, cnt = run_numba(name, med, g, RAY, bounds, n)
        assert abs(cnt[:, 0].mean() - expect) < 4 * math.sqrt(expect / n), name
    _, cnt = run_numba("biased_raymarch", med, g, RAY, bounds, 10)
    assert np.all(cnt[:, 0] == 6)
    _, cnt = run_numba("track_length", med, g, RAY, bounds, n)
    assert cnt[:, 0].mean() < mbar


def test_next_flight_variance_in_empty_space():
    """Closed form: with mu = 0 and majorant m over length L, next-flight ratio tracking has
    mean 1 and variance (1 - e^{-2 m L}) / 2 (a Poisson sum of e^{-m (L - t_i)}); ratio
    tracking has variance 0. This is why next-flight loses on loose majorants."""
    med = X.make_profile(X.DENSITY_CONSTANT, 0.0)
    m, n = 3.0, 200000
    est, _ = run_numba("next_flight", med, np.zeros((1, 1, 1)), RAY, np.array([[m, 0.0]]), n)
    assert est.mean() == pytest.approx(1.0, abs=4 * math.sqrt(0.5 / n))
    assert est.var() == pytest.approx(0.5 * (1 - math.exp(-2 * m)), rel=0.05)
    est, _ = run_numba("ratio", med, np.zeros((1, 1, 1)), RAY, np.array([[m, 0.0]]), 1000)
    assert np.all(est == 1.0)


def test_biased_raymarch_converges_as_the_step_shrinks():
    """Its comb has ceil(RAYMARCH_SAMPLES_PER_MFP x sigma_maj L) points, so scaling the
    majorant by spm gives spm times as many comb points per mean free path."""
    med, mbar, mu_c, exact, _ = profile_case("hole", 0.3, 1.0)
    biases = []
    for spm in (0.25, 1.0, 4.0, 16.0):
        est, _ = run_numba("biased_raymarch", med, np.zeros((1, 1, 1)), RAY,
                           np.array([[mbar * spm, mu_c]]), 20000)
        biases.append(abs(est.mean() - exact))
    assert biases[0] > 1e-3                       # biased at a coarse step ...
    assert all(b2 < b1 for b1, b2 in zip(biases, biases[1:]))   # ... and converging
    assert biases[-1] < 1e-4


@pytest.mark.parametrize("name", list(ESTIMATORS))
def test_kernel_matches_reference(name):
    """Same rays and streams: per-estimate agreement for the vast majority, equal means."""
    rec, mbar, sets = _cloud_rays()
    label, rays, exact = sets[1]
    bounds = np.tile([mbar, 0.0], (len(rays), 1))
    if ESTIMATORS[name].homogeneous_only:
        bounds = np.tile([mbar, mbar], (len(rays), 1))
    a, ca = run_numba(name, rec.medium, rec.grid, rays, bounds, 128)
    b, cb = _ocl(name).run(rec.medium, rec.grid, rays, bounds, 128)
    same = np.isclose(a, b, rtol=1e-3, atol=1e-5) & (ca[:, 0] == cb[:, 0])
    assert same.mean() > 0.99, same.mean()
    se = math.sqrt(a.var() / a.size + b.var() / b.size)
    assert abs(a.mean() - b.mean()) <= z_bound(ALPHA) * se + 1e-6
