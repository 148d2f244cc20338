"""robustness case 11: the same scene translated 1e5 and 1e7 units from the origin renders the same
image; float32 distance accumulation must not stall (at t = 1e5 with majorant 1e3, t + dt == t).

Guards exercised:

* "scene frame" (pack.scene_frame): positions are re-centred on the medium box (and scaled by a
  power of two) in float64 before the kernels' float32 sees them. At 1e7 a float32 has an ulp
  of 1, so without it the camera alone would move by up to half a unit. "Same image" at 1e7
  can only mean the scene as written (float64 numbers in the TOML) renders as at the origin:
  the translation is removed exactly, so the image agrees statistically with the origin one.
* "entry re-basing" (enter_box, integrator.py / integrator.cl): a ray entering the box from
  far away restarts at the entry point, so tracking distances stay local to the box.
* "local distances" (the tracking loop and the per-segment estimators): every tracking loop
  accumulates the distance from the segment start, so a segment starting at t0 = 1e5 with a
  majorant of 1e3 does not stall.
"""

import math

import numpy as np

from stats import ALPHA, z_bound
from volmc.bench import transmittance_runner as TR
from volmc.check import compare_images
from tracking_runs import grid_media, walks
from volmc.constants import DENSITY_CONSTANT, TRACK_FREE_FLIGHT
from volmc.params import C_CAPPED, C_LOOKUPS
from volmc.reference import medium as X
from volmc.render import render
from volmc.scene import scene_from_dict



def _translated(raw, offset):
    """A copy of a scene dict with every position moved by ``offset`` (float64)."""
    import copy
    raw = copy.deepcopy(raw)

    def mv(p):
        return [p[i] + offset[i] for i in range(3)]
    cam = raw["camera"]
    cam["eye"], cam["target"] = mv(cam["eye"]), mv(cam["target"])
    lo, hi = raw["medium"]["bounds"]
    raw["medium"]["bounds"] = [mv(lo), mv(hi)]
    for lt in raw["lights"]:
        if lt["type"] == "point":
            lt["position"] = mv(lt["position"])
    return raw


def _two_sample_ok(a, b, m_tests):
    d = a.film.mean() - b.film.mean()
    se = np.sqrt(a.film.variance_of_mean() + b.film.variance_of_mean())
    return np.abs(d / np.where(se > 0, se, np.inf)).max(), z_bound(ALPHA, m_tests)


def test_case11_translated_scene_renders_the_same_image(backend, tmp_path):
    """robustness case 11: a heterogeneous scene with every light type (environment, directional,
    point), an off-centre box and an HG phase renders, translated by 1e5 and by 1e7 along
    (1, 0.5, -0.75), the same image as at the origin: per-pixel two-sample z-tests with both
    variances (independent seeds) and image means, Sidak over both translations; nothing
    capped or dropped."""
    rng = np.random.default_rng(11)
    np.save(tmp_path / "g.npy", (rng.random((6, 7, 8)) ** 2).astype(np.float32))
    raw = {"camera": {"eye": [0.3, 0.7, 4.0], "target": [0.0, 0.5, 0.0], "fov": 45,
                      "resolution": [16, 16]},
           "medium": {"bounds": [[-1.0, -0.5, -1.0], [1.0, 1.5, 1.0]], "scale": 3.0,
                      "albedo": 0.8, "phase": {"type": "hg", "g": 0.3},
                      "density": {"file": str(tmp_path / "g.npy")}},
           "lights": [{"type": "environment", "radiance": 0.3},
                      {"type": "directional", "direction": [1, -1, -0.5], "irradiance": 1.5},
                      {"type": "point", "position": [0.5, 2.5, 0.5], "intensity": 2.0}],
           "render": {"spp": 64, "seed": 3}}
    base = render(scene_from_dict(raw), backend=backend, progress=False)
    m = 2 * base.film.mean().size
    for dist in (1e5, 1e7):
        far = _translated(raw, (dist, 0.5 * dist, -0.75 * dist))
        far["render"]["seed"] = 4
        res = render(scene_from_dict(far), backend=backend, progress=False)
        assert np.all(np.isfinite(res.film.mean()))
        assert res.counters["capped"] == 0 and res.counters["dropped"] == 0
        zmax, bound = _two_sample_ok(base, res, m)
        assert zmax < bound, (dist, zmax, bound)
        cmp = compare_images(base.film.mean(), base.film.variance_of_mean(), res.film.mean(),
                             res.film.variance_of_mean())
        assert max(abs(z) for z in cmp.mean_z) < z_bound(ALPHA, 6), (dist, cmp.mean_z)


def test_case11_far_camera_does_not_stall(backend, tmp_path):
    """robustness case 11, rays that travel 1e5 before the medium: a perspective camera 1e5 units
    from a grid whose global majorant is 1e3 (mean extinction about 2) sees the same image as
    an orthographic camera 4 units away framing the same square (at 1e5 the perspective rays
    are parallel to 1e-5). Without local distances delta tracking from t0 = 1e5 stalls
    (steps of 1e-3 against a float32 ulp of 0.008) and either hits the step cap or biases the
    collisions. Asserted: no capped walk, and per-pixel two-sample z-tests plus image means."""
    g = np.full((6, 6, 6), 2e-3)
    g[1:3, 2:5, 1:4] = 1e-3
    g[3, 3, 3] = 1.0   # one very dense voxel sets the majorant to 1e3
    np.save(tmp_path / "g.npy", g.astype(np.float32))
    common = {"medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "scale": 1e3, "albedo": 0.7,
                         "density": {"file": str(tmp_path / "g.npy")}},
              "lights": [{"type": "environment", "radiance": 1.0},
                         {"type": "directional", "direction": [0.3, -1, -0.4],
                          "irradiance": 1.0}],
              "render": {"spp": 32, "max_depth": 2, "majorant": "global", "max_steps": 20000,
                         "transmittance": "ratio"}}
    far = dict(common, camera={"eye": [0, 0, 1e5], "target": [0, 0, 0], "resolution": [12, 12],
                               "fov": math.degrees(2 * math.atan(1.2 / 1e5))})
    near = dict(common, camera={"type": "orthographic", "eye": [0, 0, 4], "target": [0, 0, 0],
                                "size": 2.4, "resolution": [12, 12]})
    near = dict(near, render=dict(common["render"], seed=1))
    a = render(scene_from_dict(far), backend=backend, progress=False)
    b = render(scene_from_dict(near), backend=backend, progress=False)
    for r in (a, b):
        assert r.counters["capped"] == 0 and r.counters["dropped"] == 0
        assert np.all(np.isfinite(r.film.mean()))
    zmax, bound = _two_sample_ok(a, b, a.film.mean().size)
    assert zmax < bound, zmax
    cmp = compare_images(a.film.mean(), a.film.variance_of_mean(), b.film.mean(),
                         b.film.variance_of_mean())
    assert max(abs(z) for z in cmp.mean_z) < z_bound(ALPHA, 3), cmp.mean_z


# Function level: a unit-extinction segment [1e5 - 1, 1e5 + 1] along +x from the origin under a
# majorant of 1e3 (mean 2000 tentative collisions): T = e^-2, P(collision) = 1 - e^-2.
FAR_T0, FAR_T1, FAR_MBAR, FAR_STEPS = 1e5 - 1.0, 1e5 + 1.0, 1e3, 20000
FAR_RAY = np.array([[0, 0, 0, 1, 0, 0, FAR_T0, FAR_T1, 0]], np.float64)
FAR_BMIN, FAR_BMAX = (1e5 - 1.0, -1.0, -1.0), (1e5 + 1.0, 1.0, 1.0)


def test_case11_tracking_far_along_the_ray(backend, monkeypatch):
    """robustness case 11, function level: ratio tracking and track-length estimation over
    [1e5 - 1, 1e5 + 1] with extinction 1 and majorant 1e3 give T = e^-2 (Sidak z-test), with
    Poisson(2000) lookups for ratio tracking and no capped walk; delta-tracking free flight
    over a unit grid there collides with probability 1 - e^-2 (binomial z-test) and every
    collision lies in the segment."""
    monkeypatch.setattr(TR, "MAX_STEPS", FAR_STEPS)
    bound = z_bound(ALPHA, 4)
    med = X.make_profile(DENSITY_CONSTANT, 1.0)
    bounds = np.array([[FAR_MBAR, 0.0]])
    n = 3000
    for name in ("ratio", "track_length"):
        if backend == "numba":
            est, cnt = TR.run_numba(name, med, np.zeros((1, 1, 1)), FAR_RAY, bounds, n, seed=7)
        else:
            est, cnt = TR.OpenCLEstimator(name).run(med, np.zeros((1, 1, 1)), FAR_RAY, bounds,
                                                   n, seed=7)
        assert cnt[:, C_CAPPED].sum() == 0, name
        se = est.std(ddof=1) / math.sqrt(n)
        assert abs(est.mean() - math.exp(-2.0)) < bound * se, (name, est.mean())
        if name == "ratio":
            lk = cnt[:, C_LOOKUPS].mean()
            assert abs(lk - 2000.0) < bound * math.sqrt(2000.0 / n), lk
    grid = np.ones((2, 2, 2))
    n = 4000
    media = grid_media(FAR_BMIN, FAR_BMAX, 1.0, grid, 1, sigma_maj=FAR_MBAR)
    t, _, _ = walks(backend, TRACK_FREE_FLIGHT, False, media, grid, FAR_RAY, n, 9, FAR_STEPS)
    capped = int(np.sum(t == -2.0))
    assert capped == 0
    hit = t >= 0
    p = 1 - math.exp(-2.0)
    assert abs(hit.mean() - p) < bound * math.sqrt(p * (1 - p) / n), hit.mean()
    assert np.all((t[hit] >= FAR_T0) & (t[hit] <= FAR_T1))
