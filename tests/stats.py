"""Statistical test helpers shared by the test suite.

Conventions: every helper takes explicit data and returns a p-value or a z-score; tests
compare against ALPHA, Sidak-corrected over the number of hypotheses they make, so each
test function has a false-failure rate of at most ALPHA (with fixed seeds, a given test
either always passes or always fails).
"""

import math

import numpy as np
from scipy import stats as sps

#: Family-wise false-failure rate of one statistical test function.
ALPHA = 0.01


def sidak(alpha, m):
    """Per-hypothesis significance level for m independent hypotheses at family level alpha."""
    return 1.0 - (1.0 - alpha) ** (1.0 / m)


def z_bound(alpha, m=1):
    """Two-sided normal bound |z| for m hypotheses at family level alpha (Sidak)."""
    return float(sps.norm.isf(0.5 * sidak(alpha, m)))


def chi2_pvalue(observed, expected, min_expected=5.0):
    """Pearson chi-square goodness of fit, pooling cells with expected count < min_expected
    (in increasing order of expectation) into one cell, as Mitsuba's ChiSquareTest does.

    Returns (p-value, degrees of freedom). Observed counts in cells with zero expectation
    make the p-value 0 (the sampler produced an impossible value)."""
    observed = np.asarray(observed, np.float64).ravel()
    expected = np.asarray(expected, np.float64).ravel()
    if np.any((expected == 0) & (observed > 0)):
        return 0.0, 0
    order = np.argsort(expected)
    obs, exp = observed[order], expected[order]
    pooled_o, pooled_e = 0.0, 0.0
    keep_o, keep_e = [], []
    for o, e in zip(obs, exp):
        if e < min_expected:
            pooled_o += o
            pooled_e += e
        else:
            keep_o.append(o)
            keep_e.append(e)
    if pooled_e > 0:
        if pooled_e < min_expected and keep_e:
            # Merge the pool into the smallest kept cell so every cell has enough mass.
            keep_o[0] += pooled_o
            keep_e[0] += pooled_e
        else:
            keep_o.append(pooled_o)
            keep_e.append(pooled_e)
    keep_o = np.array(keep_o)
    keep_e = np.array(keep_e)
    dof = len(keep_e) - 1
    if dof < 1:
        return 1.0, 0
    chi2 = float(np.sum((keep_o - keep_e) ** 2 / keep_e))
    return float(sps.chi2.sf(chi2, dof)), dof


def cos_phi_bins(pdf_cos, n_cos, n_phi, n_samples, quad_nodes=24):
    """Expected counts over a (cos theta, phi) grid for a pdf symmetric about the axis.

    ``pdf_cos(mu)`` is the density per steradian as a function of cos theta (vectorised).
    Bin edges in cos are chosen so each holds roughly equal probability (from a fine
    numerical CDF), so peaked phase functions still get many informative cells; the expected
    count of each cell is then integrated with Gauss-Legendre quadrature inside the cell.
    Returns (cos_edges, expected[n_cos, n_phi])."""
    fine = np.linspace(-1.0, 1.0, 200001)
    dens = pdf_cos(fine) * 2.0 * math.pi
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(fine))])
    cdf /= cdf[-1]
    edges = np.interp(np.linspace(0.0, 1.0, n_cos + 1), cdf, fine)
    edges[0], edges[-1] = -1.0, 1.0
    edges = np.unique(edges)
    x, w = np.polynomial.legendre.leggauss(quad_nodes)
    probs = []
    for a, b in zip(edges[:-1], edges[1:]):
        mu = 0.5 * (b - a) * x + 0.5 * (a + b)
        probs.append(0.5 * (b - a) * np.sum(w * pdf_cos(mu)) * 2.0 * math.pi)
    probs = np.array(probs)
    expected = np.repeat(probs[:, None] / n_phi, n_phi, axis=1) * n_samples
    return edges, expected


def direction_cos_phi(dirs, axis):
    """cos theta and phi in [0, 2 pi) of unit directions about a unit axis."""
    axis = np.asarray(axis, np.float64)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    s = np.cross(axis, helper)
    s /= np.linalg.norm(s)
    t = np.cross(axis, s)
    mu = np.clip(dirs @ axis, -1.0, 1.0)
    phi = np.mod(np.arctan2(dirs @ t, dirs @ s), 2.0 * math.pi)
    return mu, phi
