"""robustness case 12: the scene scaled by s in {1e-4, 1e4} about the origin, with extinction scaled
by 1 / s, renders the same image.

Radiance is invariant under this change for environment and directional lights; a point light
of intensity I gives irradiance I / r^2, so the scaled scene uses intensity I s^2 (the same
irradiance at the scaled distances). Guard exercised: "scene frame" (pack.scene_frame), which
packs positions in units of a power of two near the box's half-size, so the kernels' float32
sees nearly the same numbers at every scale (it would also hold far beyond 1e+-4, where
float32 squared distances of point lights over- or underflow).
"""

import copy
import math

import numpy as np

from stats import ALPHA, z_bound
from volmc.render import render
from volmc.scene import scene_from_dict



def _scaled(raw, s):
    raw = copy.deepcopy(raw)
    cam = raw["camera"]
    cam["eye"] = [s * x for x in cam["eye"]]
    cam["target"] = [s * x for x in cam["target"]]
    if "size" in cam:
        cam["size"] *= s
    raw["medium"]["bounds"] = [[s * x for x in p] for p in raw["medium"]["bounds"]]
    raw["medium"]["scale"] /= s
    for lt in raw["lights"]:
        if lt["type"] == "point":
            lt["position"] = [s * x for x in lt["position"]]
            lt["intensity"] *= s * s
    return raw


def test_case12_scaled_scene_renders_the_same_image(backend, tmp_path):
    """robustness case 12 on both backends:

    * a heterogeneous grid scene with environment, directional and point lights, HG phase and
      an off-centre box, scaled by 1e-4 and 1e4: per-pixel two-sample z-tests (both
      variances, independent seeds) and image means against the unscaled render, Sidak over
      both scales; nothing capped or dropped, lookups per sample within 2 % (same work);
    * a homogeneous pure absorber seen by an orthographic camera, scaled likewise: every pixel
      is exactly L exp(-tau) (float32 rounding only)."""
    rng = np.random.default_rng(12)
    np.save(tmp_path / "g.npy", (rng.random((5, 6, 7)) ** 2).astype(np.float32))
    raw = {"camera": {"eye": [0.4, 0.9, 3.5], "target": [0.0, 0.4, 0.0], "fov": 45,
                      "resolution": [16, 16]},
           "medium": {"bounds": [[-1.0, -0.5, -1.0], [1.0, 1.5, 1.0]], "scale": 2.5,
                      "albedo": 0.85, "phase": {"type": "hg", "g": -0.3},
                      "density": {"file": str(tmp_path / "g.npy")}},
           "lights": [{"type": "environment", "radiance": 0.25},
                      {"type": "directional", "direction": [-1, -1, -0.3], "irradiance": 1.2},
                      {"type": "point", "position": [0.8, 2.0, 1.2], "intensity": 3.0}],
           "render": {"spp": 64, "seed": 5}}
    base = render(scene_from_dict(raw), backend=backend, progress=False)
    n = base.film.mean().size
    bound = z_bound(ALPHA, 2 * (n + 3))
    spp_total = base.film.spp * n / 3
    for s in (1e-4, 1e4):
        sc = _scaled(raw, s)
        sc["render"]["seed"] = 6
        res = render(scene_from_dict(sc), backend=backend, progress=False)
        assert np.all(np.isfinite(res.film.mean()))
        assert res.counters["capped"] == 0 and res.counters["dropped"] == 0
        d = res.film.mean() - base.film.mean()
        var = res.film.variance_of_mean() + base.film.variance_of_mean()
        z = d / np.sqrt(np.where(var > 0, var, np.inf))
        assert np.abs(z).max() < bound, (s, np.abs(z).max())
        zm = d.sum(axis=(0, 1)) / np.sqrt(var.sum(axis=(0, 1)))
        assert np.abs(zm).max() < bound, (s, zm)
        lk_a = base.counters["lookups"] / spp_total
        lk_b = res.counters["lookups"] / spp_total
        assert abs(lk_b / lk_a - 1) < 0.02, (s, lk_a, lk_b)

    absorber = {"camera": {"type": "orthographic", "eye": [0.2, -0.1, 3.0], "target": [0.2, -0.1, 0],
                           "size": 1.5, "resolution": [4, 4]},
                "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": 1.0, "scale": 0.75,
                           "albedo": 0.0},
                "lights": [{"type": "environment", "radiance": 0.8}],
                "render": {"spp": 4}}
    expected = 0.8 * math.exp(-0.75 * 2.0)
    rtol = 1e-12 if backend == "numba" else 2e-6
    for s in (1.0, 1e-4, 1e4):
        img = render(scene_from_dict(_scaled(absorber, s)), backend=backend,
                     progress=False).film.mean()
        assert np.allclose(img, expected, rtol=rtol, atol=0), (s, img.min(), img.max())
