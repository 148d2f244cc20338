"""Agreement and speed of volmc against a peer renderer on the same scene.

Agreement: a per-pixel Welch test of volmc's image against the peer's. volmc's variance of
the mean has spp - 1 degrees of freedom (treated as exact); the peer's comes from the spread
of K independent passes (K - 1 degrees of freedom), so each pixel's statistic is compared
with Student's t at its Welch-Satterthwaite degrees of freedom, Sidak-corrected over all
pixel channels at family level ALPHA. The image means are compared the same way, with the
peer's variance taken from its K pass means directly.

Speed: time and RMSE of each renderer at the same spp against a high-spp reference (volmc,
independent seed). The reference's own noise adds its mean variance to every measured MSE;
that known amount is subtracted, so the RMSE printed is that against the exact image.
Equal-error time ratio = (t_peer * mse_peer) / (t_volmc * mse_volmc): Monte Carlo MSE falls
as 1/t, so this is how much longer the peer needs to reach volmc's error.
"""

import math
from dataclasses import dataclass

import numpy as np

from ..check import ALPHA, ROUNDING_ABS, ROUNDING_REL, sidak_level, student_t_two_sided


#: Relative standard error below which volmc's pixel counts as constant (see agreement).
SPREAD_REL = 1e-7


def welch_pvalues(diff, var_a, var_b, dof_b):
    """Two-sided p-values of diff / sqrt(var_a + var_b); var_b has dof_b degrees of freedom."""
    var = var_a + var_b
    with np.errstate(divide="ignore", invalid="ignore"):
        dof = np.where(var_b > 0, var * var / (var_b * var_b / dof_b), np.inf)
        z = np.where(var > 0, diff / np.sqrt(var), np.where(diff == 0, 0.0, np.inf))
    dof = np.maximum(dof, dof_b)
    return student_t_two_sided(z, dof), z


@dataclass
class Agreement:
    """Outcome of volmc against a peer: image means, their z-scores, per-pixel test."""
    mean_volmc: tuple
    mean_peer: tuple
    mean_z: tuple
    mean_p: float
    max_abs_z: float
    min_p: float
    per_test_alpha: float
    frac_rejected: float
    n_tests: int
    n_untested: int = 0

    @property
    def passed(self):
        return self.min_p >= self.per_test_alpha and self.means_agree

    @property
    def means_agree(self):
        """The image-mean test alone (Sidak over the three channels)."""
        return self.mean_p >= sidak_level(ALPHA, 3)

    def summary(self, peer="peer"):
        verdict = "AGREE" if self.passed else "DIFFER"
        mz = ", ".join(f"{z:+.2f}" for z in self.mean_z)
        rel = ", ".join(f"{100 * (a / b - 1):+.3f} %" if b else "n/a"
                        for a, b in zip(self.mean_volmc, self.mean_peer))
        return (f"{verdict}: image mean volmc - {peer} (R, G, B): {rel}, in standard errors "
                f"{mz}; max |z| per pixel {self.max_abs_z:.2f}, smallest p {self.min_p:.2e} "
                f"(Sidak per-test level {self.per_test_alpha:.2e} over {self.n_tests} pixel "
                f"channels); {100 * self.frac_rejected:.3f} % rejected" +
                (f"; {self.n_untested} pixel channels untested (the peer's passes all alike)"
                 if self.n_untested else ""))


def agreement(mean_v, var_v, mean_p, var_p, pass_means_p, low_p=None):
    """Compare volmc (mean, variance of the mean) with a peer rendered in K passes.

    pass_means_p: [K, 3] image means of the peer's passes (for the image-mean test); low_p:
    each pixel channel's least pass value (default 0: every pass value is >= 0)."""
    mean_v, var_v = np.asarray(mean_v, np.float64), np.asarray(var_v, np.float64)
    mean_p, var_p = np.asarray(mean_p, np.float64), np.asarray(var_p, np.float64)
    k = len(pass_means_p)
    # A pixel channel whose peer passes came out alike while volmc's samples vary is one where
    # a rare event (a real collision in thin medium, a shadow ray getting through a dense
    # one, a phase-sampled ray meeting a small light) was never drawn by the peer. Its
    # sample variance is then 0 though the true one is not, and nothing in the data bounds
    # it: one event can move the pixel far beyond its mean (a track-length transmittance
    # jumps from 0 to the full light). The same holds where one pass alone drew such events:
    # the spread of K values of which K - 1 are alike says nothing about the next pass.
    # How many passes carry the pixel's excess e = mean - (its least pass value) is
    #     n = K e^2 / (e^2 + (K - 1) var),  var the variance of the mean,
    # exact for n passes of equal value above the rest (n = 0 when all are alike). Where
    # n < 2 the pixel channel is left out of the per-pixel test and counted; the image-mean
    # test below still includes it. Where both renderers came out constant (a background
    # seen directly), they are compared up to float32 rounding.
    # Float32 rounding in either renderer (as in volmc check) is not a statistical difference,
    # and passes that differ by no more than it came out alike.
    rounding = ROUNDING_REL * np.maximum(np.abs(mean_v), np.abs(mean_p)) + ROUNDING_ABS
    # volmc's samples vary where its standard error exceeds what float64 sums of identical
    # float32 samples leave (far below float32 rounding: a smooth estimate, such as
    # equiangular samples along a camera ray through thin medium, can vary less than that).
    varies = var_v > (SPREAD_REL * np.maximum(np.abs(mean_v), np.abs(mean_p))) ** 2
    alike = var_p * k <= rounding ** 2
    excess = mean_p - (0.0 if low_p is None else np.asarray(low_p, np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        carried = k * excess ** 2 / (excess ** 2 + (k - 1) * var_p)
    # The converse: where every one of volmc's samples came out 0 while the peer's passes
    # vary, volmc never drew the pixel's rare event (a real collision in a thin sliver of
    # medium at the edge of a pixel, reached by distance sampling with probability tau), so
    # its variance of 0 says nothing either. Only exact zeros: a constant that is not 0 (a
    # background seen directly) is compared.
    never = (mean_v == 0.0) & (var_v == 0.0) & ~alike
    untested = (varies & (alike | ~(carried >= 2.0))) | never
    p, z = welch_pvalues(mean_v - mean_p, var_v + rounding ** 2, var_p, k - 1)
    p, z = np.where(untested, 1.0, p), np.where(untested, 0.0, z)
    per = sidak_level(ALPHA, p.size)
    n_pix = mean_v.shape[0] * mean_v.shape[1]
    mz, mp = [], []
    pm = np.asarray(pass_means_p, np.float64)
    for c in range(3):
        d = float(mean_v[..., c].mean() - mean_p[..., c].mean())
        # Rounding again: an image without noise (a background seen through nothing) has
        # variance 0 on both sides.
        va = float(var_v[..., c].sum()) / n_pix ** 2 + float(
            (ROUNDING_REL * max(abs(mean_v[..., c].mean()), abs(mean_p[..., c].mean())) +
             ROUNDING_ABS) ** 2)
        vb = float(pm[:, c].var(ddof=1)) / k
        pc, zc = welch_pvalues(np.array(d), np.array(va), np.array(vb), k - 1)
        mz.append(float(zc))
        mp.append(float(pc))
    return Agreement(tuple(mean_v.mean(axis=(0, 1))), tuple(mean_p.mean(axis=(0, 1))),
                     tuple(mz), min(mp), float(np.abs(z).max()), float(p.min()), per,
                     float(np.mean(p < per)), int(p.size), int(untested.sum()))


def rmse_to_reference(image, ref_mean, ref_var):
    """RMSE of ``image`` against the exact image, estimated from a noisy reference.

    E[(x - r)^2] = (x - exact)^2 + Var(r): the reference's mean variance of the mean is
    subtracted (never below zero)."""
    d = np.asarray(image, np.float64) - np.asarray(ref_mean, np.float64)
    mse = float(np.mean(d * d)) - float(np.mean(ref_var))
    return math.sqrt(max(mse, 0.0))


def equal_error_time_ratio(t_a, rmse_a, t_b, rmse_b):
    """How many times longer B needs than A to reach the same RMSE (MSE proportional to 1/t);
    None when A's RMSE is 0 (an exact image, as an absorber's: no ratio is defined)."""
    if rmse_a == 0.0:
        return None
    return (t_b * rmse_b ** 2) / (t_a * rmse_a ** 2)
