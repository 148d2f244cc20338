"""Samplers: chi-square goodness of fit, pdf consistency, moments, hard inputs."""

import math

import numpy as np
import pytest
from numba import njit
from scipy import stats as sps

from stats import ALPHA, chi2_pvalue, cos_phi_bins, direction_cos_phi, sidak, z_bound
from volmc.reference.phase import (PHASE_HG, PHASE_ISOTROPIC, hg_eval, hg_sample,
                                   hg_sample_cos, phase_eval, phase_sample)
from volmc.reference.rng import uniforms
from volmc.reference.sampling import (coordinate_system, exponential_pdf, sample_exponential,
                                      sample_uniform_sphere)

N = 1_000_000
AXIS = np.array([0.36, -0.48, 0.8])  # unit, not aligned with any coordinate axis
HG_G = [-0.99, -0.9, -0.6, -0.3, -1e-3, -1e-4, -1e-6, 0.0, 1e-6, 1e-4, 1e-3, 0.3, 0.6, 0.9,
        0.99]


@njit(cache=True)
def _hg_samples(u, g, axis):
    n = u.shape[0] // 2
    dirs = np.empty((n, 3))
    pdfs = np.empty(n)
    d_in = (axis[0], axis[1], axis[2])
    for i in range(n):
        w, pdf = hg_sample(u[2 * i], u[2 * i + 1], d_in, g)
        dirs[i, 0], dirs[i, 1], dirs[i, 2] = w
        pdfs[i] = pdf
    return dirs, pdfs


@njit(cache=True)
def _sphere_samples(u):
    n = u.shape[0] // 2
    dirs = np.empty((n, 3))
    for i in range(n):
        w, _ = sample_uniform_sphere(u[2 * i], u[2 * i + 1])
        dirs[i, 0], dirs[i, 1], dirs[i, 2] = w
    return dirs


@njit(cache=True)
def _hg_eval_vec(mu, g):
    out = np.empty(mu.shape[0])
    for i in range(mu.shape[0]):
        out[i] = hg_eval(mu[i], g)
    return out


def _chi2_directions(dirs, pdf_cos, axis, n_cos=40, n_phi=20):
    mu, phi = direction_cos_phi(dirs, axis)
    edges, expected = cos_phi_bins(pdf_cos, n_cos, n_phi, len(dirs))
    ci = np.clip(np.searchsorted(edges, mu, side="right") - 1, 0, len(edges) - 2)
    pj = np.minimum((phi / (2 * math.pi) * n_phi).astype(int), n_phi - 1)
    observed = np.bincount(ci * n_phi + pj, minlength=expected.size).reshape(expected.shape)
    return chi2_pvalue(observed, expected)[0]


def test_hg_chi_square():
    """HG sampling matches hg_eval over (cos, phi) cells for every g (Sidak over g)."""
    a = sidak(ALPHA, len(HG_G))
    for k, g in enumerate(HG_G):
        dirs, _ = _hg_samples(uniforms(7, k, 0, 2, 2 * N), g, AXIS)
        p = _chi2_directions(dirs, lambda mu: _hg_eval_vec(np.asarray(mu, np.float64), g), AXIS)
        assert p > a, f"g={g}: p={p:.3g}"


def test_uniform_sphere_chi_square():
    dirs = _sphere_samples(uniforms(8, 0, 0, 2, 2 * N))
    p = _chi2_directions(dirs, lambda mu: np.full_like(np.asarray(mu, float), 1 / (4 * math.pi)),
                         np.array([0.0, 0.0, 1.0]))
    assert p > ALPHA
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)


def test_hg_pdf_of_sample_equals_evaluated_phase():
    for k, g in enumerate([-0.99, -0.5, 0.0, 1e-5, 0.7, 0.99]):
        dirs, pdfs = _hg_samples(uniforms(9, k, 0, 2, 20000), g, AXIS)
        ev = _hg_eval_vec(np.clip(dirs @ AXIS, -1, 1), g)
        assert np.allclose(pdfs, ev, rtol=1e-6), g


def test_hg_normalised_and_mean_cosine():
    """The phase function integrates to 1 and the sample mean of cos equals g (4 s.e.)."""
    x, w = np.polynomial.legendre.leggauss(400)
    bound = z_bound(ALPHA, 7)
    for k, g in enumerate([-0.9, -0.3, 0.0, 0.3, 0.6, 0.9, 0.99]):
        # Integrate in the variable s = (1 + g^2 - 2 g mu)^(1/2)-free form: split [-1, 1] finely.
        pieces = np.linspace(-1, 1, 201)
        total = 0.0
        for a, b in zip(pieces[:-1], pieces[1:]):
            mu = 0.5 * (b - a) * x + 0.5 * (a + b)
            total += 0.5 * (b - a) * np.sum(w * _hg_eval_vec(mu, g)) * 2 * math.pi
        assert abs(total - 1.0) < 1e-6, (g, total)
        dirs, _ = _hg_samples(uniforms(10, k, 0, 2, 2 * N), g, AXIS)
        mu = dirs @ AXIS
        z = (mu.mean() - g) / (mu.std() / math.sqrt(len(mu)))
        assert abs(z) < bound, (g, z)


@pytest.mark.parametrize("g", [0.95, -0.95])
def test_hg_forward_backward_ratio(g):
    """P(cos > 0) matches the closed-form CDF; catches a sign slip at negative g."""
    # CDF(mu) = (1 - g^2) / (2 g) ((1 + g^2 - 2 g mu)^(-1/2) - 1 / (1 + g)); P(cos > 0) = 1 - CDF(0).
    p_fwd = 1.0 - (1 - g * g) / (2 * g) * (1 / math.sqrt(1 + g * g) - 1 / (1 + g))
    dirs, _ = _hg_samples(uniforms(11, int(g > 0), 0, 2, 2 * N), g, AXIS)
    frac = np.mean(dirs @ AXIS > 0)
    se = math.sqrt(p_fwd * (1 - p_fwd) / (len(dirs)))
    assert abs(frac - p_fwd) < z_bound(ALPHA, 2) * se
    assert (frac > 0.5) == (g > 0)


@pytest.mark.parametrize("g", [0.9999, -0.9999, 1 - 2**-24, -(1 - 2**-24), 1e-12, -1e-12])
@pytest.mark.parametrize("u", [0.0, 2**-24, 0.5, 1 - 2**-24])
def test_hg_hard_inputs(g, u):
    cos, sin, pdf = hg_sample_cos(u, g)
    assert -1.0 <= cos <= 1.0 and 0.0 <= sin <= 1.0
    assert abs(cos * cos + sin * sin - 1.0) < 1e-12
    assert math.isfinite(pdf) and pdf > 0
    (w, pdf2) = hg_sample(u, 0.25, tuple(AXIS), g)
    assert abs(math.sqrt(sum(c * c for c in w)) - 1.0) < 1e-12
    assert pdf2 == pdf
    if abs(g) <= 0.9999:
        # Evaluated from cos alone the pdf is accurate to about 1e-16 / (1 - |cos|).
        assert math.isclose(pdf, hg_eval(cos, g), rel_tol=1e-6)
    # from the directions (their chord), at every g
    assert math.isclose(pdf, phase_eval(PHASE_HG, g, tuple(AXIS), w), rel_tol=1e-6)


def test_phase_dispatch():
    d = (0.0, 0.0, 1.0)
    w, pdf = phase_sample(PHASE_ISOTROPIC, 0.7, 0.3, 0.6, d)
    assert pdf == pytest.approx(1 / (4 * math.pi))
    assert phase_eval(PHASE_ISOTROPIC, 0.7, d, w) == pytest.approx(1 / (4 * math.pi))
    w, pdf = phase_sample(PHASE_HG, 0.7, 0.3, 0.6, d)
    assert pdf == pytest.approx(phase_eval(PHASE_HG, 0.7, d, w))
    # g > 0 scatters forward: the peak is at cos = 1.
    assert phase_eval(PHASE_HG, 0.7, d, d) > phase_eval(PHASE_HG, 0.7, d, (0.0, 0.0, -1.0))


@njit(cache=True)
def _exp_samples(u, a):
    out = np.empty(u.shape[0])
    for i in range(u.shape[0]):
        out[i] = sample_exponential(u[i], a)[0]
    return out


def test_exponential_ks_and_pdf():
    a = 2.5
    t = _exp_samples(uniforms(12, 0, 0, 2, 200_000), a)
    assert np.all(np.isfinite(t)) and t.min() >= 0
    assert sps.kstest(t, "expon", args=(0, 1 / a)).pvalue > ALPHA
    for u in (0.0, 0.5, 1 - 2**-24):
        tt, pdf = sample_exponential(u, a)
        assert math.isfinite(tt)
        assert pdf == pytest.approx(exponential_pdf(tt, a))
    assert sample_exponential(0.5, 0.0)[0] == math.inf


@pytest.mark.parametrize("n", [(0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (-0.0, 0.0, -1.0),
                               (1.0, 0.0, 0.0), (0.36, -0.48, 0.8), (0.0, 1.0, -0.0)])
def test_coordinate_system_orthonormal(n):
    s, t = coordinate_system(n)
    m = np.array([s, t, n])
    assert np.allclose(m @ m.T, np.eye(3), atol=1e-12)
    assert np.allclose(np.cross(s, t), n, atol=1e-12)
