"""Transmittance and free-flight estimators against exact answers (4 standard errors)."""

import math

import numpy as np
import pytest
from stats import ALPHA, sidak, z_bound
from tracking_runs import grid_media, walks
from volmc.bench.transmittance_runner import run_numba
from volmc.constants import TRACK_FREE_FLIGHT
from volmc.params import C_CAPPED, C_LOOKUPS
from volmc.reference.grid import grid_lookup
from volmc.reference.optical_depth import optical_depth_exact

BMIN = (-1.0, -0.5, -2.0)
BMAX = (1.0, 1.5, 0.0)
INV_EXT = tuple(1.0 / (b - a) for a, b in zip(BMIN, BMAX))
MAX_STEPS = 1_000_000


def _estimates(kind, grid, scale, mbar, o, d, t0, t1, n, seed):
    """n estimates (ratio tracking: kind 0, track length: 1) along one ray through the grid
    under the global majorant mbar; (estimates, counters summed over them)."""
    nz, ny, nx = grid.shape
    media = grid_media(BMIN, BMAX, scale, grid, 1, sigma_maj=mbar)
    ray = np.array([[*o, *d, t0, t1, 0.0]])
    est, cnt = run_numba(("ratio", "track_length")[kind], media, grid, ray, [[mbar, 0.0]], n,
                         seed)
    return est, cnt.sum(axis=0)


def _ray(rng):
    """A random segment inside the box: origin inside, unit direction, [0, exit)."""
    o = np.array(BMIN) + rng.random(3) * (np.array(BMAX) - np.array(BMIN))
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    with np.errstate(divide="ignore"):
        ta = (np.array(BMIN) - o) / d
        tb = (np.array(BMAX) - o) / d
    t1 = float(np.min(np.maximum(ta, tb)))
    return tuple(o), tuple(d), 0.0, t1


CASES = [
    # (name, grid kind, scale, majorant factor)
    ("homogeneous tight", "const", 1.5, 1.0),
    ("homogeneous loose x2", "const", 1.5, 2.0),
    ("homogeneous loose x10", "const", 0.8, 10.0),
    ("random grid", "random", 3.0, 1.0),
    ("random grid loose", "random", 3.0, 3.0),
]


def _grid(kind, rng):
    if kind == "const":
        return np.full((3, 4, 5), 0.7)
    return rng.random((5, 6, 7)) ** 2


@pytest.mark.parametrize("estimator", [0, 1], ids=["ratio", "track_length"])
def test_transmittance_matches_exact(estimator):
    """Mean of 20000 estimates within the Sidak bound (about 4 s.e.) of exp(-tau), tau exact."""
    rng = np.random.default_rng(5)
    n_rays = 6
    bound = z_bound(ALPHA, len(CASES) * n_rays)
    for name, kind, scale, factor in CASES:
        grid = _grid(kind, rng)
        mbar = scale * grid.max() * factor
        for r in range(n_rays):
            o, d, t0, t1 = _ray(rng)
            tau = optical_depth_exact(grid, BMIN, BMAX, scale, o, d, t0, t1)
            exact = math.exp(-tau)
            est, cnt = _estimates(estimator, grid, scale, mbar, o, d, t0, t1, 20000, r)
            se = est.std(ddof=1) / math.sqrt(est.size)
            if se == 0.0:
                assert est[0] == pytest.approx(exact, abs=1e-12), name
                continue
            z = (est.mean() - exact) / se
            assert abs(z) < bound, f"{name} ray {r}: T={exact:.4f} mean={est.mean():.4f} z={z:.2f}"
            assert cnt[C_CAPPED] == 0


def test_ratio_tracking_lookups_equal_majorant_optical_depth():
    grid = np.full((2, 2, 2), 0.5)
    o, d, t0, t1 = (0.0, 0.5, -1.0), (1.0, 0.0, 0.0), 0.0, 1.0
    mbar = 4.0
    _, cnt = _estimates(0, grid, 1.0, mbar, o, d, t0, t1, 50000, 1)
    mean_lookups = cnt[C_LOOKUPS] / 50000
    # Lookups are Poisson(mbar (t1 - t0)): standard error sqrt(4 / 50000).
    assert abs(mean_lookups - mbar * (t1 - t0)) < 4 * math.sqrt(mbar / 50000)


def test_ratio_tracking_variance_closed_form():
    """Homogeneous medium, majorant m, extinction s over length L: Var = e^{-2sL}(e^{s^2 L/m} - 1)."""
    s, L = 1.0, 1.0
    grid = np.full((2, 2, 2), 1.0)
    o, d = (-1.0, 0.5, -1.0), (1.0, 0.0, 0.0)
    for m in (2.0, 10.0):
        est, _ = _estimates(0, grid, s, m, o, d, 0.0, L, 200000, 3)
        var = math.exp(-2 * s * L) * (math.exp(s * s * L / m) - 1)
        assert est.var(ddof=1) == pytest.approx(var, rel=0.1)


def test_optical_depth_exact_against_fine_quadrature():
    """The piecewise Gauss-Legendre ground truth equals a very fine midpoint rule."""
    rng = np.random.default_rng(2)
    grid = rng.random((4, 5, 6))
    for _ in range(5):
        o, d, t0, t1 = _ray(rng)
        exact = optical_depth_exact(grid, BMIN, BMAX, 2.0, o, d, t0, t1)
        n = 200000
        ts = t0 + (np.arange(n) + 0.5) * (t1 - t0) / n
        vals = [grid_lookup(grid, BMIN, INV_EXT, tuple(np.array(o) + t * np.array(d)))
                for t in ts[::100]]
        coarse = 2.0 * np.mean(vals) * (t1 - t0)
        assert exact == pytest.approx(coarse, rel=2e-3)


def _free_flights(grid, scale, mbar, o, d, t1, n, seed):
    """Delta-tracking collision distances (inf on escape) under the global majorant mbar."""
    media = grid_media(BMIN, BMAX, scale, grid, 1, sigma_maj=mbar)
    t, _, _ = walks("numba", TRACK_FREE_FLIGHT, False, media, grid,
                    [[*o, *d, 0.0, t1, 0.0]], n, seed)
    return np.where(t >= 0.0, t, math.inf)


def test_delta_tracking_distance_distribution():
    """Chi-square of collision distances against 1 - T(t) from the exact optical depth."""
    from stats import chi2_pvalue
    rng = np.random.default_rng(9)
    grid = rng.random((5, 6, 7))
    o, d, _, t1 = _ray(np.random.default_rng(4))
    n = 200000
    t = _free_flights(grid, 2.0, 2.0 * grid.max() * 1.5, o, d, t1, n, 3)
    edges = np.linspace(0.0, t1, 31)
    cdf = np.array([1 - math.exp(-optical_depth_exact(grid, BMIN, BMAX, 2.0, o, d, 0.0, e))
                    for e in edges])
    expected = np.append(np.diff(cdf), 1 - cdf[-1]) * n
    observed = np.append(np.histogram(t[np.isfinite(t)], bins=edges)[0],
                         np.sum(~np.isfinite(t)))
    p, _ = chi2_pvalue(observed, expected)
    assert p > ALPHA
