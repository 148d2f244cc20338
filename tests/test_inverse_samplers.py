"""Inverse samplers: every sampler with a closed-form inverse maps its sample back to the
uniforms it came from (round trip), in the reference (float64) and in the kernels (float32,
fed the same inputs as the reference: twins)."""

import math

import numpy as np
import pytest
from numba import njit

from cl_harness import f3, out_buf, run, to_dev
from volmc.reference.phase import hg_invert_cos, hg_sample, hg_sample_cos, invert_hg_sample
from volmc.reference.rng import uniforms
from volmc.reference.sampling import (invert_exponential_sample, invert_uniform_sphere,
                                      sample_exponential, sample_uniform_sphere)


GS = (-0.99, -0.9, -0.5, -1e-3, 0.0, 1e-6, 0.3, 0.75, 0.95, 0.999)
D_IN = (0.36, -0.48, 0.8)


@njit(cache=True)
def _round_trips(us, g):
    """(u1, u2) back from HG directions and uniform-sphere directions sampled from us."""
    n = us.shape[0]
    hg = np.empty((n, 2))
    sph = np.empty((n, 2))
    for i in range(n):
        w, _ = hg_sample(us[i, 0], us[i, 1], D_IN, g)
        hg[i, 0], hg[i, 1] = invert_hg_sample(w, D_IN, g)
        v, _ = sample_uniform_sphere(us[i, 0], us[i, 1])
        sph[i, 0], sph[i, 1] = invert_uniform_sphere(v)
    return hg, sph


def _u_pairs(n, seed):
    u = uniforms(seed, 0, 0, 2, 2 * n).reshape(n, 2)
    # Stay away from the poles, where the azimuth is not defined.
    return u[(u[:, 0] > 1e-3) & (u[:, 0] < 1 - 1e-3)]


def _circular(a, b):
    """Distance of two azimuth fractions in [0, 1) on the circle."""
    d = np.abs(a - b)
    return np.minimum(d, 1.0 - d)


@pytest.mark.parametrize("g", GS)
def test_hg_and_sphere_round_trip_in_the_reference(g):
    us = _u_pairs(4000, 3)
    hg, sph = _round_trips(us, g)
    assert np.allclose(sph[:, 0], us[:, 0], atol=1e-12)
    assert np.all(_circular(sph[:, 1], us[:, 1]) < 1e-9)
    # u1 through cos: the cosine keeps ~1e-16 absolute, so u1 is recovered to the CDF's slope.
    assert np.allclose(hg[:, 0], us[:, 0], atol=1e-7), np.abs(hg[:, 0] - us[:, 0]).max()
    assert np.all(_circular(hg[:, 1], us[:, 1]) < 1e-6)


def test_hg_invert_cos_is_the_cdf():
    """u = hg_invert_cos(cos) is the HG probability of cos' <= cos: it matches the numerical
    integral of the phase function, for g of either sign and near 0 (no division by g)."""
    from scipy import integrate
    from volmc.reference.phase import hg_eval
    for g in (-0.9, -1e-9, 0.0, 1e-9, 0.5, 0.99):
        for c in (-1.0, -0.3, 0.0, 0.7, 0.999, 1.0):
            cdf = integrate.quad(lambda x: 2 * math.pi * hg_eval(x, g), -1.0, c,
                                 epsabs=1e-12, limit=200)[0]
            assert hg_invert_cos(c, g) == pytest.approx(cdf, abs=1e-8), (g, c)
            assert hg_sample_cos(hg_invert_cos(c, g), g)[0] == pytest.approx(c, abs=1e-9)


def test_exponential_round_trip():
    for a in (1e-3, 0.7, 50.0):
        u = uniforms(4, 0, 0, 2, 2000)
        t = np.array([sample_exponential(x, a)[0] for x in u])
        back = np.array([invert_exponential_sample(x, a) for x in t])
        assert np.allclose(back, u, rtol=1e-12, atol=1e-15)


def test_kernel_inverses_match_the_reference(lanes):
    """The kernels' inverses, fed the reference's directions and distances: equal to float32
    precision, and round trips close to the uniforms."""
    us = _u_pairs(2000, 5)
    for g in (-0.9, 0.0, 0.75):
        dirs = np.array([hg_sample(a, b, D_IN, g)[0] for a, b in us])
        gs = np.full(len(dirs), g, np.float32)
        out, ob = out_buf((len(dirs), 2))
        run("t_invert_hg_sample", len(dirs), to_dev(dirs.astype(np.float32).ravel()), f3(D_IN),
            to_dev(gs), ob, outs=[(out, ob)])
        assert np.allclose(out[:, 0], us[:, 0], atol=2e-3)
        assert np.all(_circular(out[:, 1], us[:, 1]) < 2e-3)
        d32 = tuple(float(x) for x in np.float32(D_IN))
        ref = np.array([invert_hg_sample(tuple(float(x) for x in w), d32, float(np.float32(g)))
                        for w in dirs.astype(np.float32)])
        assert np.allclose(out[:, 0], ref[:, 0], atol=1e-4)
        assert np.all(_circular(out[:, 1], ref[:, 1]) < 1e-4)
    dirs = np.array([sample_uniform_sphere(a, b)[0] for a, b in us])
    out, ob = out_buf((len(dirs), 2))
    run("t_invert_uniform_sphere", len(dirs), to_dev(dirs.astype(np.float32).ravel()), ob,
        outs=[(out, ob)])
    assert np.allclose(out[:, 0], us[:, 0], atol=1e-6)
    assert np.all(_circular(out[:, 1], us[:, 1]) < 1e-5)
    t = np.array([sample_exponential(x, 2.5)[0] for x in us[:, 0]]).astype(np.float32)
    out, ob = out_buf(len(t))
    run("t_invert_exponential", len(t), to_dev(t), np.float32(2.5), ob, outs=[(out, ob)])
    assert np.allclose(out, us[:, 0], rtol=1e-5, atol=1e-7)
