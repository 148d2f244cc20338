"""robustness case 1-3: Henyey-Greenstein sampling and uniform random numbers, on both backends.

Every test runs the OpenCL twin (kernels/testing.cl through tests/cl_harness.py, float32)
and the Numba reference (float64) on the same uniforms (both backends draw bit-identical
Philox numbers, exact in float32). Statistical tests use fixed seeds and a family
false-failure rate of ALPHA, Sidak-corrected over the hypotheses of one test function.
"""

import math

import numpy as np
import pytest
from scipy import stats as sps

from cl_harness import f3, out_buf, run, to_dev
from stats import ALPHA, chi2_pvalue, direction_cos_phi, sidak, z_bound
from test_sampling import _exp_samples, _hg_samples
from volmc.reference.phase import hg_sample, hg_sample_cos
from volmc.reference.rng import uniforms


AXIS = np.array([0.36, -0.48, 0.8])   # unit, not aligned with any coordinate axis
CASE1_G = [0.0, 1e-6, -1e-6, 1e-4, -1e-4, 1e-3, -1e-3, 0.6, -0.6, 0.9, -0.9, 0.99, -0.99,
           0.999, -0.999]
N_DIRS = 1_000_000


def _f32(x):
    """The float32 value of x, as a Python float (what both backends are given)."""
    return float(np.float32(x))


def hg_directions(backend, u, g):
    """Directions sampled about AXIS from HG(g) with uniforms u (2 per direction), as float64
    unit vectors [n, 3] (kernel output renormalised in float64), and their pdfs."""
    if backend == "numba":
        return _hg_samples(u, g, AXIS)
    n = u.size // 2
    out, ob = out_buf((n, 5))   # direction, pdf, phase_eval there
    run("t_hg_sample", n, to_dev(u.astype(np.float32)), to_dev(np.full(n, g, np.float32)),
        f3(AXIS), ob, outs=[(out, ob)])
    dirs = out[:, :3].astype(np.float64)
    assert np.all(np.isfinite(out)), "non-finite direction or pdf"
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-6)
    return dirs / np.linalg.norm(dirs, axis=1)[:, None], out[:, 3].astype(np.float64)


def hg_survival(dirs, axis, g):
    """P(cos > cos of each direction) under HG(g), i.e. 1 - CDF, in closed form.

    With omc = 1 - cos, S = (1 + g) omc / ((sqrt(D) + 1 - g) sqrt(D)), D = 1 + g^2 - 2 g cos,
    written so that nothing cancels: omc and 1 + cos come from |w -+ axis|^2 / 2 and D is a
    sum of non-negative terms. (Equivalent to the textbook (1 - g^2) / (2 g) ((1 - g)^-1 -
    D^-1/2), which divides by g.) S is uniform on [0, 1] for exact HG samples whatever g is,
    including g within 1e-3 of +-1 where a binning in cos would need 1e-6-wide cells."""
    a = axis / np.linalg.norm(axis)
    omc = 0.5 * np.sum((dirs - a) ** 2, axis=1)
    opc = 0.5 * np.sum((dirs + a) ** 2, axis=1)
    D = (1 - g) ** 2 + 2 * g * omc if g >= 0 else (1 + g) ** 2 - 2 * g * opc
    sd = np.sqrt(D)
    return (1 + g) * omc / ((sd + 1 - g) * sd)


def test_case01_hg_chi_square_and_mean_cosine(backend, lanes):
    """robustness case 1: HG sampling at g in {0, +-1e-6, +-1e-4, +-1e-3, +-0.6, +-0.9, +-0.99,
    +-0.999} passes a chi-square test over (HG CDF of cos, phi) cells with equal expectations
    (40 x 20 cells, 10^6 samples), and the sample mean of cos equals g within the Sidak bound.
    Sidak over 2 hypotheses per g."""
    a = sidak(ALPHA, 2 * len(CASE1_G))
    zb = z_bound(ALPHA, 2 * len(CASE1_G))
    n_s, n_phi = 40, 20
    fails = []
    for k, g in enumerate(CASE1_G):
        g = _f32(g)
        dirs, pdf = hg_directions(backend, uniforms(101, k, 0, 2, 2 * N_DIRS), g)
        assert np.all(pdf > 0) and np.all(np.isfinite(pdf))
        s = hg_survival(dirs, AXIS, g)
        _, phi = direction_cos_phi(dirs, AXIS)
        si = np.clip((s * n_s).astype(int), 0, n_s - 1)
        pj = np.clip((phi / (2 * math.pi) * n_phi).astype(int), 0, n_phi - 1)
        observed = np.bincount(si * n_phi + pj, minlength=n_s * n_phi)
        p, _ = chi2_pvalue(observed, np.full(n_s * n_phi, len(dirs) / (n_s * n_phi)))
        cos = 1.0 - 0.5 * np.sum((dirs - AXIS) ** 2, axis=1)
        z = (cos.mean() - g) / (cos.std(ddof=1) / math.sqrt(cos.size))
        if not p > a or not abs(z) < zb:
            fails.append(f"g={g}: chi-square p={p:.3g} (need > {a:.2g}), E[cos] z={z:.2f}")
    assert not fails, "; ".join(fails)


@pytest.mark.parametrize("g", [0.95, -0.95])
def test_case01_hg_forward_backward_ratio(backend, g, lanes):
    """robustness case 1: at g = +-0.95 the fraction of forward samples (cos > 0) equals the
    closed-form S(0) = (1 + g) / ((sqrt(1 + g^2) + 1 - g) sqrt(1 + g^2)) (0.989 at g = 0.95,
    0.011 at -0.95), so the forward/backward ratio is right and a sign slip at negative g,
    which swaps the two, fails by hundreds of standard errors."""
    g = _f32(g)
    r = math.sqrt(1 + g * g)
    p_fwd = (1 + g) / ((r + 1 - g) * r)
    dirs, _ = hg_directions(backend, uniforms(102, int(g > 0), 0, 2, 2 * N_DIRS), g)
    frac = float(np.mean(dirs @ AXIS > 0))
    se = math.sqrt(p_fwd * (1 - p_fwd) / len(dirs))
    ratio = frac / (1 - frac)
    assert abs(frac - p_fwd) < z_bound(ALPHA, 4) * se, \
        f"forward/backward ratio {ratio:.4g}, expected {p_fwd / (1 - p_fwd):.4g}"
    assert (frac > 0.5) == (g > 0)


CASE2_G = [0.9999, -0.9999, 1 - 2.0**-24, -(1 - 2.0**-24), 1e-6, -1e-6, 1e-12, -1e-12]
CASE2_U = [0.0, 2.0**-24, 0.5, 1 - 2.0**-24]


def _hg_exact(c, s, g):
    """HG value at the angle whose (cos, sin) pair is (c, s), from 1 -+ cos obtained without
    cancellation (s^2 / (1 +- c)), so angles below float resolution of cos still count."""
    omc = s * s / (1 + c) if c > 0 else 1 - c
    opc = s * s / (1 - c) if c < 0 else 1 + c
    D = (1 - g) ** 2 + 2 * g * omc if g >= 0 else (1 + g) ** 2 - 2 * g * opc
    return (1 - g) * (1 + g) / (4 * math.pi * D * math.sqrt(D))


def test_case02_hg_extreme_g_and_u(backend, lanes):
    """robustness case 2: g in {+-0.9999, +-(1 - 2^-24)} (and tiny g +-1e-6, +-1e-12, where a
    naive inversion divides by g) with u in {0, 2^-24, 0.5, 1 - 2^-24}: cos in [-1, 1],
    sin in [0, 1], cos^2 + sin^2 = 1; the direction is finite and unit, at angle (cos, sin)
    from the incoming direction; the pdf is finite, positive and equals the phase function
    evaluated at the sample's angle (float32: to 1e-4 relative, float64: 1e-9)."""
    gs = np.array([_f32(g) for g in CASE2_G for _ in CASE2_U])
    us = np.array([u for _ in CASE2_G for u in CASE2_U])
    u2 = 0.3
    if backend == "opencl":
        d_in = AXIS.astype(np.float32).astype(np.float64)   # what the kernel is given
        n = gs.size
        csp, cb = out_buf((n, 3))
        run("t_hg_sample_cos", n, to_dev(us.astype(np.float32)), to_dev(gs.astype(np.float32)),
            cb, outs=[(csp, cb)])
        uu = np.stack([us, np.full(n, u2)], 1).astype(np.float32)
        w5, wb = out_buf((n, 5))   # direction, pdf, phase_eval there
        run("t_hg_sample", n, to_dev(uu.ravel()), to_dev(gs.astype(np.float32)), f3(d_in), wb,
            outs=[(w5, wb)])
        csp, w4 = csp.astype(np.float64), w5[:, :4].astype(np.float64)
        tol_pdf, tol_dir = 1e-4, 2e-6
    else:
        d_in = AXIS / np.linalg.norm(AXIS)
        csp = np.array([hg_sample_cos(u, g) for u, g in zip(us, gs)])
        w4 = np.array([(*w, p) for w, p in (hg_sample(u, u2, tuple(d_in), g)
                                            for u, g in zip(us, gs))])
        tol_pdf, tol_dir = 1e-9, 1e-12
    for (c, s, pdf), (wx, wy, wz, pdf2), g, u in zip(csp, w4, gs, us):
        where = f"g={g!r} u={u!r}: cos={c!r} sin={s!r} pdf={pdf!r}"
        assert -1.0 <= c <= 1.0 and 0.0 <= s <= 1.0, where
        assert abs(c * c + s * s - 1.0) < 10 * tol_dir, where
        assert math.isfinite(pdf) and pdf > 0 and pdf2 == pytest.approx(pdf, rel=1e-6), where
        assert pdf == pytest.approx(_hg_exact(c, s, g), rel=tol_pdf), where
        w = np.array([wx, wy, wz])
        assert np.all(np.isfinite(w)) and abs(np.linalg.norm(w) - 1.0) < tol_dir, where
        assert abs(w @ d_in - c) < tol_dir and \
            abs(np.linalg.norm(np.cross(w, d_in)) - s) < tol_dir, where


# A Philox position whose word is 0xffffffb6 (found by search): seed 0, pixel 13918442,
# sample 0, STREAM_TEST (2), draw 0. Its uniform is the largest possible, 1 - 2^-24; the
# naive float32 conversion word * 2^-32 rounds it to exactly 1.0, where -log(1 - u) = inf.
MAX_WORD_STREAM = (0, 13918442, 0, 2)
MAX_WORD = 0xFFFFFFB6


def _kernel_uniforms(seed, pixel, sample, stream, n):
    out, ob = out_buf(n)
    run("t_uniforms", 1, np.uint64(seed), np.uint32(pixel), np.uint32(sample), np.uint32(stream),
        np.uint32(n), ob, outs=[(out, ob)])
    return out


def _kernel_exponential(u, a):
    out, ob = out_buf((u.size, 2))
    run("t_exponential", u.size, to_dev(np.asarray(u, np.float32)), np.float32(a), ob,
        outs=[(out, ob)])
    return out[:, 0].astype(np.float64), out[:, 1].astype(np.float64)


def test_case03_uniforms_never_one(backend, lanes):
    """robustness case 3: uniforms are never exactly 1.0, even for the largest Philox word (where
    uint32 * 2^-32 rounds to 1.0 in float32): that draw gives 1 - 2^-24 and a finite
    exponential distance 24 ln 2 / a; 2^20 draws of each of 4 streams lie in [0, 1)."""
    assert np.float32(MAX_WORD) * np.float32(2.0**-32) == np.float32(1.0)   # the hard input
    if backend == "opencl":
        u_max = _kernel_uniforms(*MAX_WORD_STREAM, 4)[0]
        t, pdf = _kernel_exponential(np.array([u_max]), 2.5)
        t, pdf = t[0], pdf[0]
        draws = [_kernel_uniforms(7, p, 3, s, 1 << 20) for p, s in ((0, 0), (1, 1), (5, 2))]
    else:
        u_max = uniforms(*MAX_WORD_STREAM, 4)[0]
        t = _exp_samples(np.array([u_max]), 2.5)[0]
        pdf = 2.5 * math.exp(-2.5 * t)
        draws = [uniforms(7, p, 3, s, 1 << 20) for p, s in ((0, 0), (1, 1), (5, 2))]
    assert u_max == 1.0 - 2.0**-24 and u_max < 1.0
    assert math.isfinite(t) and t == pytest.approx(24 * math.log(2) / 2.5, rel=1e-6)
    assert math.isfinite(pdf) and pdf > 0
    for u in draws:
        assert u.min() >= 0.0 and u.max() < 1.0 and np.all(np.isfinite(u))


def test_case03_exponential_distances_ks(backend, lanes):
    """robustness case 3: exponential distances -log(1 - u) / a from the generator's uniforms pass
    a Kolmogorov-Smirnov test against Exp(a) at rates a in {1e-3, 2.5, 1e3} (2 * 10^5
    samples each, Sidak over the rates); all are finite and >= 0."""
    rates = [1e-3, 2.5, 1e3]
    a_level = sidak(ALPHA, len(rates))
    for k, a in enumerate(rates):
        a = _f32(a)
        if backend == "opencl":
            t, _ = _kernel_exponential(_kernel_uniforms(13, k, 0, 2, 200_000), a)
        else:
            t = _exp_samples(uniforms(13, k, 0, 2, 200_000), a)
        assert np.all(np.isfinite(t)) and t.min() >= 0.0
        p = sps.kstest(t, "expon", args=(0, 1 / a)).pvalue
        assert p > a_level, f"a={a}: KS p={p:.3g}"
