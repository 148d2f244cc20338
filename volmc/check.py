"""Image-level comparison of two renders (kernel against reference, or any two backends).

Both renders use independent seeds (seed and seed + 1), so their per-pixel difference has
variance var_a + var_b (each render's own variance of the mean) and the z-test below has
its stated false-failure rate: a pixel fails when |z| exceeds the two-sided Sidak bound
for ALPHA over all pixels and channels; the image means are compared the same way.
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


def sidak_z(alpha, m):
    """Two-sided normal bound for m hypotheses at family level alpha (Sidak correction)."""
    from statistics import NormalDist
    per = 1.0 - (1.0 - alpha) ** (1.0 / m)
    return NormalDist().inv_cdf(1.0 - per / 2.0)


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


def compare_images(mean_a, var_a, mean_b, var_b, alpha=ALPHA):
    """Per-pixel and image-mean z-tests of two images with their variances of the mean."""
    mean_a, mean_b = np.asarray(mean_a, np.float64), np.asarray(mean_b, np.float64)
    # Float32 arithmetic makes a kernel's pixel differ from the float64 reference by a few
    # ulps even where both are exact (zero variance): that rounding is added to the variance
    # so it is not mistaken for a statistical difference.
    rounding = ROUNDING_REL * np.maximum(np.abs(mean_a), np.abs(mean_b)) + ROUNDING_ABS
    var = np.asarray(var_a, np.float64) + np.asarray(var_b, np.float64) + rounding ** 2
    diff = mean_a - mean_b
    z = diff / np.sqrt(var)
    bound = sidak_z(alpha, z.size)
    n_pix = diff.shape[0] * diff.shape[1]
    mz = []
    for c in range(3):
        se = math.sqrt(float(var[..., c].sum())) / n_pix
        mz.append(float(diff[..., c].mean()) / se)
    return Comparison(bound, float(np.abs(z).max()), float(np.mean(np.abs(z) > bound)),
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
                         rb.film.variance_of_mean())
    return cmp, ra, rb
