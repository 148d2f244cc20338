"""The thin lens's sample (issue 22, part 3): the concentric mapping of the square onto the
disc is uniform (chi-square) and inverts, and the kernel's twins (sample_uniform_disc,
invert_uniform_disc) equal the reference at every lane width. Statistical tests have fixed
seeds and a family false-failure rate of ALPHA (1 %) each."""

import math

import numpy as np
from numba import njit

from cl_harness import out_buf, run, to_dev
from stats import ALPHA, chi2_pvalue
from volmc.reference.rng import uniforms
from volmc.reference.sampling import invert_uniform_disc, sample_uniform_disc, uniform_disc_pdf

EDGE_U = np.array([0.0, 2.0**-24, 0.25, 0.5, 0.75, 1 - 2.0**-24])


@njit(cache=True)
def _disc_points(u):
    n = u.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        (x, y), pdf = sample_uniform_disc(u[i, 0], u[i, 1])
        out[i, 0], out[i, 1], out[i, 2] = x, y, pdf
    return out


@njit(cache=True)
def _disc_inverses(p):
    out = np.empty((p.shape[0], 2))
    for i in range(p.shape[0]):
        out[i, 0], out[i, 1] = invert_uniform_disc((p[i, 0], p[i, 1]))
    return out


def _disc_chi2(x, y, n_r=20, n_phi=20):
    """p-value of points on the unit disc against the uniform density, over n_r x n_phi
    cells of equal area (equal steps of r^2 and of the angle)."""
    ri = np.minimum(((x * x + y * y) * n_r).astype(int), n_r - 1)
    phi = np.arctan2(y, x) % (2 * math.pi)
    pj = np.minimum((phi / (2 * math.pi) * n_phi).astype(int), n_phi - 1)
    observed = np.bincount(ri * n_phi + pj, minlength=n_r * n_phi)
    return chi2_pvalue(observed, np.full(n_r * n_phi, len(x) / (n_r * n_phi)))[0]


def test_uniform_disc_chi_square():
    """Concentric mapping: uniform on the disc (equal-area cells, 10^6 points, level ALPHA),
    inside it, with pdf 1 / pi. The test has power: the naive polar warp r = u1 fails it."""
    u = uniforms(21, 0, 0, 2, 2_000_000).reshape(-1, 2)
    p = _disc_points(u)
    assert np.all(p[:, 0] ** 2 + p[:, 1] ** 2 <= 1.0 + 1e-15)
    assert np.all(p[:, 2] == 1.0 / math.pi) and uniform_disc_pdf() == 1.0 / math.pi
    assert _disc_chi2(p[:, 0], p[:, 1]) > ALPHA
    r, phi = u[:, 0], 2 * math.pi * u[:, 1]
    assert _disc_chi2(r * np.cos(phi), r * np.sin(phi)) < 1e-12


def test_uniform_disc_round_trip():
    """invert_uniform_disc(sample_uniform_disc(u)) = u, on both wedges, their borders and the
    square's edges and centre."""
    u = np.concatenate([np.array([[a, b] for a in EDGE_U for b in EDGE_U]),
                        uniforms(22, 0, 0, 2, 200_000).reshape(-1, 2)])
    back = _disc_inverses(_disc_points(u)[:, :2])
    assert np.allclose(back, u, rtol=0, atol=1e-12), np.abs(back - u).max()


def test_uniform_disc_kernel_matches_reference(lanes):
    """The kernel's warp and inverse, fed the reference's inputs: equal to float32 precision."""
    u = np.concatenate([np.array([[a, b] for a in EDGE_U for b in EDGE_U]),
                        uniforms(23, 0, 0, 2, 8000).reshape(-1, 2)]).astype(np.float32)
    ref = _disc_points(u.astype(np.float64))
    pts = ref[:, :2].astype(np.float32)
    out, ob = out_buf((len(u), 5))
    run("t_uniform_disc", len(u), to_dev(u.ravel()), to_dev(pts.ravel()), ob, outs=[(out, ob)])
    assert np.allclose(out[:, :2], ref[:, :2], rtol=0, atol=1e-6)
    assert np.all(out[:, 2] == np.float32(1.0 / math.pi))
    back = _disc_inverses(pts.astype(np.float64))
    assert np.allclose(out[:, 3:], back, rtol=0, atol=2e-6), np.abs(out[:, 3:] - back).max()
