"""robustness case 10: extremely dense media (scale * density = 1e30; majorant optical depth 1e6).

Guards exercised: "transmittance roulette" (estimators.py / estimators.h and the per-segment
product in shadow_transmittance), the step cap (counted in ``capped``), "entry re-basing"
(integrator.py / integrator.cl: a dense medium is entered exactly on its face) and "local
distances" (tracking loops accumulate from the segment start, so 1e-30 steps still add up).
"""

import math

import numpy as np

from stats import ALPHA, z_bound
from volmc.bench.transmittance_runner import OpenCLEstimator, run_numba
from volmc.params import C_CAPPED, C_LOOKUPS
from volmc.reference import medium as X
from volmc.constants import TR_RR_THRESHOLD
from volmc.render import mean_and_stderr, render
from volmc.scene import scene_from_dict

RAY = np.array([[0, 0, 0, 1, 0, 0, 0, 1, 0]], np.float64)
_OCL = {}


def _estimate(backend, name, med, L, mbar, mu_c, n, seed):
    rays = RAY.copy()
    rays[0, 7] = L
    bounds = np.array([[mbar, mu_c]])
    g = np.zeros((1, 1, 1))
    if backend == "numba":
        return run_numba(name, med, g, rays, bounds, n, seed)
    if name not in _OCL:
        _OCL[name] = OpenCLEstimator(name)
    return _OCL[name].run(med, g, rays, bounds, n, seed)


# (estimator, profile, L, mbar, mu_c, lookups without roulette)
ROULETTE_CASES = [
    # T = e^-10 under a majorant twice the extinction: every walk falls below the threshold.
    ("ratio", X.make_profile(X.DENSITY_CONSTANT, 5.0), 2.0, 10.0, 0.0, 20.0),
    ("next_flight", X.make_profile(X.DENSITY_CONSTANT, 5.0), 2.0, 10.0, 0.0, 20.0),
    ("residual_ratio", X.make_profile(X.DENSITY_CONSTANT, 5.0), 2.0, 10.0, 1.0, 18.0),
    # T = e^-8, near the threshold, on a ramp: roulette decides in part of the walks (the
    # mean is what is checked there).
    ("ratio", X.make_profile(X.DENSITY_RAMP, 2.0, 14.0, L=1.0), 1.0, 28.0, 0.0, None),
    ("next_flight", X.make_profile(X.DENSITY_RAMP, 2.0, 14.0, L=1.0), 1.0, 28.0, 0.0, None),
    ("residual_ratio", X.make_profile(X.DENSITY_RAMP, 2.0, 14.0, L=1.0), 1.0, 28.0, 2.0, None),
]


def test_case10_transmittance_roulette_is_unbiased_and_cheap(backend):
    """robustness case 10, estimator level: ratio, next-flight and residual ratio tracking end their
    walks by Russian roulette once the running transmittance is below TR_RR_THRESHOLD. The
    mean stays exp(-tau) (Sidak z-test against the closed form) while the mean lookup count
    falls well below the roulette-free expectation (majorant optical depth); at a majorant
    optical depth of 1e6 a walk costs a few lookups instead of hitting the 1e6 step cap."""
    n = 40000
    bound = z_bound(ALPHA, len(ROULETTE_CASES) + 3)
    for k, (name, med, L, mbar, mu_c, no_rr_lookups) in enumerate(ROULETTE_CASES):
        est, cnt = _estimate(backend, name, med, L, mbar, mu_c, n, seed=100 + k)
        exact = math.exp(-X.optical_depth_profile(med, 0.0, L))
        assert np.all(np.isfinite(est)) and est.min() >= 0.0
        se = est.std(ddof=1) / math.sqrt(n)
        assert abs(est.mean() - exact) < bound * se, (name, est.mean(), exact, se)
        lookups = cnt[:, C_LOOKUPS].mean()
        if no_rr_lookups is not None:
            assert lookups < 0.8 * no_rr_lookups, (name, lookups, no_rr_lookups)
        assert cnt[:, C_CAPPED].sum() == 0
    # Majorant optical depth 1e6 (extinction 5e5 under a majorant 1e6 over unit length).
    for k, name in enumerate(("ratio", "next_flight", "residual_ratio")):
        med = X.make_profile(X.DENSITY_CONSTANT, 5e5)
        est, cnt = _estimate(backend, name, med, 1.0, 1e6, 1.0, 2000, seed=200 + k)
        assert np.all(np.isfinite(est)) and est.min() >= 0.0
        assert est.max() <= TR_RR_THRESHOLD * 1.0001   # e^-5e5 = 0: nothing large survives
        assert cnt[:, C_LOOKUPS].mean() < 40, (name, cnt[:, C_LOOKUPS].mean())
        assert cnt[:, C_CAPPED].sum() == 0


def _scene(tmp_path, density, scale, render_extra=None, lights=None, albedo=1.0, res=8,
           spp=256):
    if isinstance(density, np.ndarray):
        path = tmp_path / f"d{abs(hash(density.tobytes()))}.npy"
        np.save(path, density.astype(np.float32))
        density = {"file": str(path)}
    raw = {"camera": {"eye": [0.3, 0.2, 4.0], "target": [0, 0, 0], "fov": 40,
                      "resolution": [res, res]},
           "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": density, "scale": scale,
                      "albedo": albedo},
           "lights": lights or [{"type": "environment", "radiance": 0.5}],
           "render": dict({"spp": spp, "max_depth": -1}, **(render_extra or {}))}
    return scene_from_dict(raw)


def _sane(res):
    img = res.film.mean()
    assert np.all(np.isfinite(img)) and img.min() >= 0.0
    assert np.all(np.isfinite(res.film.variance_of_mean()))
    assert res.counters["dropped"] == 0
    return img


def test_case10_dense_media_render(backend, tmp_path):
    """robustness case 10, image level, on both backends:

    * white furnace (albedo 1, environment L, unbounded depth) at extinction 1e30, homogeneous,
      as a constant grid and as a random grid: every pixel equals L (per-pixel z-test and
      image mean, Sidak), nothing capped or dropped. At 1e30 every walk collapses onto the box
      face in float32 and float64 alike; the face point must see the outside (entered exactly
      on the face), or the furnace darkens;
    * a grid with an empty shell at scale 1e30 under a global majorant: delta tracking cannot
      cross the empty shell in steps of 1e-30, so walks hit render.max_steps = 500; they are
      cut and counted in ``capped`` and the render finishes with a finite image (bounded steps,
      never a hang);
    * majorant optical depth 1e6 along rays (scale 5e5) with ratio-tracking shadow rays: the
      image is finite, nothing is capped, and a shadow ray costs a few lookups (transmittance
      roulette) instead of 1e6."""
    rng = np.random.default_rng(10)
    rand = 0.2 + 0.8 * rng.random((8, 8, 8))
    L = 0.5
    furnaces = [("homogeneous", 1.0), ("constant grid", np.ones((4, 4, 4))),
                ("random grid", rand)]
    m = 3 * 64 * len(furnaces) + 3 * len(furnaces)
    bound = z_bound(ALPHA, m)
    for label, density in furnaces:
        res = render(_scene(tmp_path, density, 1e30), backend=backend, progress=False)
        img = _sane(res)
        se = np.sqrt(res.film.variance_of_mean())
        z = (img - L) / np.where(se > 0, se, np.inf)
        assert np.abs(z).max() < bound, (label, np.abs(z).max())
        mean, mse = mean_and_stderr(res)
        assert np.all(np.abs(mean - L) < bound * mse), (label, mean)
        assert res.counters["capped"] == 0, label
        assert res.counters["scatter_events"] > 0

    shell = np.zeros((8, 8, 8))
    shell[2:-2, 2:-2, 2:-2] = 1.0
    res = render(_scene(tmp_path, shell, 1e30, {"majorant": "global", "max_steps": 500},
                        spp=16), backend=backend, progress=False)
    _sane(res)
    assert res.counters["capped"] > 0
    assert res.stats()["paths_capped"] == res.counters["capped"]

    lights = [{"type": "environment", "radiance": 0.5},
              {"type": "directional", "direction": [1, -1, -1], "irradiance": 2.0}]
    res = render(_scene(tmp_path, rand, 5e5, {"transmittance": "ratio", "majorant": "global"},
                        lights, albedo=0.9, spp=64), backend=backend, progress=False)
    img = _sane(res)
    assert img.max() > 0.0
    assert res.counters["capped"] == 0
    per_shadow = res.counters["lookups"] / res.counters["shadow_rays"]
    assert per_shadow < 30, per_shadow
