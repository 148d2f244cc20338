"""The film's A channel (coverage A = 1 - T of each camera ray) and
render.transparent_background.

A slab seen face-on by an orthographic camera: every ray that hits it crosses the same
thickness, so T = exp(-sigma x thickness) per channel and A = 1 - mean(T). Without
scattering the renderer estimates T exactly (homogeneous); with scattering each path's
first flight gives 0 or 1 and the pixel means are z-tested (Sidak over pixels, family level
1e-3). A transparent background changes only the weight of the environment seen by camera
rays, so with the same seed opaque = transparent + (1 - A) x environment, sample by sample.
"""

import math

import numpy as np
import pytest

from stats import z_bound
from volmc.render import render
from volmc.scene import scene_from_dict

THICK = 0.5
ENV = [0.3, 0.5, 0.7]


def slab(scale=2.0, albedo=0.0, transparent=False, seed=3, spp=64, density=1.0):
    # The box is wider than the view's middle: the left quarter of the image misses it.
    return scene_from_dict({
        "camera": {"type": "orthographic", "eye": [0.0, 0.0, 3.0], "size": 2.0,
                   "resolution": [16, 8]},
        "medium": {"bounds": [[-1.0, -2.0, -THICK / 2], [3.0, 2.0, THICK / 2]],
                   "density": density, "scale": scale, "albedo": albedo,
                   "phase": {"type": "hg", "g": 0.5}},
        "lights": [{"type": "environment", "radiance": ENV},
                   {"type": "directional", "direction": [0.3, -1.0, -0.4], "irradiance": 1.5}],
        "render": {"spp": spp, "seed": seed, "max_depth": 8,
                   "transparent_background": transparent}})


def _expected_alpha(scale):
    s = scale if isinstance(scale, list) else [scale] * 3
    a = 1.0 - sum(math.exp(-c * THICK) for c in s) / 3.0
    e = np.full((8, 16), a)
    e[:, :4] = 0.0   # x < -1: these rays miss the box
    return e


@pytest.mark.parametrize("scale", [2.0, [3.0, 1.0, 0.2]])
def test_absorber_alpha_is_one_minus_transmittance(backend, scale):
    r = render(slab(scale=scale), backend=backend, progress=False)
    tol = 1e-6 if backend == "numba" else 2e-6
    assert np.allclose(r.alpha, _expected_alpha(scale), rtol=0, atol=tol)


@pytest.mark.parametrize("scale", [2.0, [3.0, 1.0, 0.2]])
def test_scattering_slab_alpha_is_unbiased(backend, scale):
    """Scattering paths: the first flight's escape (0 or 1; its hero-MIS colour weights when
    extinction is coloured) is each sample's T. Per pixel and over the image, the mean
    agrees with 1 - mean(exp(-sigma x thickness)): the pixels' z-tests (Sidak) and the
    image's at 5e-4 each, 1e-3 together."""
    r = render(slab(scale=scale, albedo=0.8, spp=256), backend=backend, progress=False)
    e = _expected_alpha(scale)
    assert np.all(r.alpha[:, :4] == 0.0)
    hit = e > 0
    var = r.film.variance_of_mean(alpha=True)[hit]
    z = (r.alpha[hit] - e[hit]) / np.sqrt(var)
    assert np.abs(z).max() < z_bound(5e-4, int(hit.sum()))
    z_mean = (r.alpha[hit] - e[hit]).mean() / math.sqrt(var.sum() / hit.sum() ** 2)
    assert abs(z_mean) < z_bound(5e-4)


def test_transparent_background_composites_to_the_opaque_image(backend):
    """Same seed, same paths: the transparent render plus (1 - A) x the environment is the
    opaque render, pixel by pixel; A is the same in both."""
    a = render(slab(albedo=0.8), backend=backend, progress=False)
    b = render(slab(albedo=0.8, transparent=True), backend=backend, progress=False)
    assert np.array_equal(a.alpha, b.alpha)
    comp = b.image + (1.0 - b.alpha)[..., None] * np.asarray(ENV)
    assert np.allclose(comp, a.image, rtol=1e-5, atol=1e-6)
    assert np.all(b.image[:, :4] == 0.0)   # missed rays see nothing
    assert b.image[:, 4:].mean() > 0.01    # the medium's own light stays
