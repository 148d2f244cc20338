"""Image-level comparison of two renders (kernel against reference, or any two backends).

Both renders use independent seeds (seed and seed + 1), so their per-pixel difference has
variance var_a + var_b (each render's own variance of the mean). A pixel channel fails when
its test's p-value is below the Sidak level for ALPHA over all pixels and channels: Welch's
t-test when the variances' degrees of freedom are given (``volmc check``: spp - 1), else a
z-test; the image means are compared by a z-test.
"""

import math
from dataclasses import dataclass

import numpy as np

#: Family-wise false-failure rate of one comparison.
ALPHA = 0.01
#: Relative and absolute size of float32 rounding differences between two renders (about 100
#: float32 ulps): far below any Monte Carlo error worth detecting.
ROUNDING_REL = 1e-5
ROUNDING_ABS = 1e-9


def sidak_level(alpha, m):
    """Per-test level of m hypotheses at family level alpha (Sidak), without the
    cancellation of 1 - (1 - alpha)^(1/m) at large m."""
    return -math.expm1(math.log1p(-alpha) / m)


def sidak_z(alpha, m):
    """Two-sided normal bound for m hypotheses at family level alpha (Sidak correction)."""
    from statistics import NormalDist
    return -NormalDist().inv_cdf(sidak_level(alpha, m) / 2.0)


@dataclass
class Comparison:
    """Outcome of comparing image A with image B."""
    z_bound: float
    max_abs_z: float
    frac_outside: float
    mean_a: tuple
    mean_b: tuple
    mean_z: tuple
    n_tests: int

    @property
    def passed(self):
        return self.max_abs_z <= self.z_bound and self.means_agree

    @property
    def means_agree(self):
        """The image-mean test alone (Sidak over the three channels)."""
        return max(abs(z) for z in self.mean_z) <= sidak_z(ALPHA, 3)

    def summary(self, name_a="A", name_b="B"):
        verdict = "AGREE" if self.passed else "DIFFER"
        mz = ", ".join(f"{z:+.2f}" for z in self.mean_z)
        return (f"{verdict}: image mean {name_a} - {name_b} in standard errors (R, G, B): {mz}; "
                f"max |z| per pixel {self.max_abs_z:.2f} (bound {self.z_bound:.2f}); "
                f"{100 * self.frac_outside:.3f} % of pixel channels outside the bound")


def _betainc_fraction(a, b, x, iterations=400):
    """The continued fraction of the regularized incomplete beta function I_x(a, b) (modified
    Lentz), elementwise; it converges fast where x < (a + 1) / (a + b + 2)."""
    tiny = 1e-300

    def fix(v):
        return np.where(np.abs(v) < tiny, tiny, v)
    c = np.ones_like(x)
    d = 1.0 / fix(1.0 - (a + b) * x / (a + 1.0))
    h = d
    for m in range(1, iterations + 1):
        m2 = 2.0 * m
        for aa in (m * (b - m) * x / ((a - 1.0 + m2) * (a + m2)),
                   -(a + m) * (a + b + m) * x / ((a + m2) * (a + 1.0 + m2))):
            d = 1.0 / fix(1.0 + aa * d)
            c = fix(1.0 + aa / c)
            h = h * d * c
        if np.all(np.abs(d * c - 1.0) < 1e-15):
            break
    return h


#: Degrees of freedom above which student_t_two_sided takes the normal tail.
NORMAL_DOF = 1e6


def student_t_two_sided(t, dof):
    """P(|T| >= |t|) for Student's t with ``dof`` degrees of freedom (arrays; dof = inf is
    the normal distribution): I_x(dof/2, 1/2) at x = dof / (dof + t^2)."""
    t, dof = np.broadcast_arrays(np.abs(np.asarray(t, np.float64)),
                                 np.asarray(dof, np.float64))
    p = np.empty(t.shape)
    # Above NORMAL_DOF the normal tail is exact to about t^4 / (4 dof) relative (1e-4 at
    # t = 5), while the beta form below loses its digits to cancellation (lgamma(a + 1/2) -
    # lgamma(a), 1 - x): at 1e16 degrees of freedom it gave 6.5e-11 for p = 2.7e-3.
    normal = ~(dof <= NORMAL_DOF)
    p[normal] = np.array([math.erfc(v / math.sqrt(2.0)) for v in t[normal].ravel()])
    tt, nu = t[~normal], dof[~normal]
    a, b = nu / 2.0, 0.5
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        x = nu / (nu + tt * tt)
        lg = np.vectorize(math.lgamma, otypes=[float])
        log_front = lg(a + b) - lg(a) - lg(b) + a * np.log(x) + b * np.log1p(-x)
        front = np.exp(log_front)
        direct = x < (a + 1.0) / (a + b + 2.0)
        xs = np.where(direct, x, 1.0 - x)
        aa, bb = np.where(direct, a, b), np.where(direct, b, a)
        frac = front * _betainc_fraction(aa, bb, xs) / aa
        inner = np.where(direct, frac, 1.0 - frac)
    p[~normal] = np.where(tt == 0.0, 1.0, np.where(np.isinf(tt), 0.0, inner))
    return np.clip(p, 0.0, 1.0)


def compare_images(mean_a, var_a, mean_b, var_b, alpha=ALPHA, dof_a=math.inf,
                   dof_b=math.inf):
    """Per-pixel and image-mean tests of two images with their variances of the mean.

    dof_a, dof_b: the degrees of freedom of each variance estimate (spp - 1 of a render;
    inf: taken as exact, a z-test). With finite ones each pixel channel's difference is
    Welch's t-test at the Welch-Satterthwaite degrees of freedom, so the stated
    false-failure rate holds at few samples too (a z-test with variances from 2 samples
    rejects far more often than its level); its p-value is reported as the normal |z| of
    the same p-value, against the same Sidak bound. The image means, sums over many pixels,
    are z-tests."""
    mean_a, mean_b = np.asarray(mean_a, np.float64), np.asarray(mean_b, np.float64)
    va, vb = np.asarray(var_a, np.float64), np.asarray(var_b, np.float64)
    # Float32 arithmetic makes a kernel's pixel differ from the float64 reference by a few
    # ulps even where both are exact (zero variance): that rounding is added to the variance
    # so it is not mistaken for a statistical difference.
    rounding = ROUNDING_REL * np.maximum(np.abs(mean_a), np.abs(mean_b)) + ROUNDING_ABS
    var = va + vb + rounding ** 2
    diff = mean_a - mean_b
    z = diff / np.sqrt(var)
    bound = sidak_z(alpha, z.size)
    if math.isinf(dof_a) and math.isinf(dof_b):
        max_z, outside = float(np.abs(z).max()), float(np.mean(np.abs(z) > bound))
    else:
        # The t tail is never lighter than the normal one, so a pixel within the normal bound
        # passes the t-test too: only the others, and the largest |z| for the report, need
        # the t p-value (a 1080p image has 6 million pixel channels).
        az = np.abs(z).ravel()
        top = np.argpartition(az, -min(64, az.size))[-min(64, az.size):]
        pick = np.union1d(np.flatnonzero(az > bound), top)
        ta, tb = np.ravel(va)[pick], np.ravel(vb)[pick]
        with np.errstate(divide="ignore", invalid="ignore"):
            denom = ta * ta / dof_a + tb * tb / dof_b
            dof = np.where(denom > 0.0, np.ravel(var)[pick] ** 2 / denom, math.inf)
        p = student_t_two_sided(az[pick], dof)
        outside = float(np.count_nonzero(p < sidak_level(alpha, z.size))) / z.size
        i = int(np.argmin(p))
        from statistics import NormalDist
        pmin = float(p[i])
        # From the lower tail: 1 - pmin / 2 rounds to 1 below pmin = 1e-16
        max_z = (-NormalDist().inv_cdf(pmin / 2.0) if 0.0 < pmin / 2.0 and pmin < 1.0
                 else 0.0 if pmin >= 1.0 else float(az[pick][i]))
    n_pix = diff.shape[0] * diff.shape[1]
    mz = []
    for c in range(3):
        se = math.sqrt(float(var[..., c].sum())) / n_pix
        mz.append(float(diff[..., c].mean()) / se)
    return Comparison(bound, max_z, outside,
                      tuple(mean_a.mean(axis=(0, 1))), tuple(mean_b.mean(axis=(0, 1))),
                      tuple(mz), int(z.size))


def check_scene(scene, backends=("opencl", "numba"), spp=None, device=None):
    """Render ``scene`` with two backends (independent seeds) and compare the images.

    Returns (Comparison, result_a, result_b)."""
    from .backends import make_backend
    from .render import render
    sa = scene if spp is None else scene.with_render(spp=spp)
    sb = sa.with_render(seed=(sa.render.seed + 1) % 2**64)
    ra = render(sa, backend=make_backend(backends[0], sa, device), progress=False)
    rb = render(sb, backend=make_backend(backends[1], sb, device), progress=False)
    cmp = compare_images(ra.film.mean(), ra.film.variance_of_mean(), rb.film.mean(),
                         rb.film.variance_of_mean(), dof_a=ra.film.spp - 1,
                         dof_b=rb.film.spp - 1)
    return cmp, ra, rb
