"""Bias-corrected ray marching on one majorant segment: the telescoping (unbiased) estimator
and the jackknife (low-bias) estimator. Twin of ``kernels/debiasing.h``.

Both start from jittered ray marching: a comb of n equidistant points with one uniform
jitter u, tau_hat = h sum_j mu(t0 + (j + u) h), h = L / n, estimates the optical depth
without bias, but exp(-tau_hat) overestimates T (Jensen), by about T Var(tau_hat) / 2. The
telescoping estimator removes that bias at random extra cost; the jackknife removes its
leading term at fixed cost.

Shared conventions (those of power_series.py): the segment is [t0, t1] along o + t d;
``mbar`` >= mu is its majorant and sets the step; ``mu_c`` (the minorant) is not used: a
constant control cancels from exp(-tau_hat) exactly (exp(-mu_c L) exp(-(tau_hat - mu_c L))
is the same number), so it can change neither estimate. Every density evaluation is one
counted ``extinction`` lookup. t1 <= t0 or mbar <= 0 returns 1 with no lookups; budgets
above ``max_steps`` are cut (C_CAPPED counted). Roulette decisions compare v = 1 - u in
(0, 1] against P(K >= k), as power_series.py does.

Both return RGB: with colour-dependent extinction channel c's optical depth is chroma_c tau
(``medium_chroma``), so one comb of lookups serves every channel and each channel's estimate
is the same formula applied to chroma_c tau_hat (the same K, jitters and levels). A grey
medium (chroma 1) gives three equal channels, each the scalar estimate bit for bit.
"""

import math

import numpy as np
from numba import njit

from ..constants import (JACKKNIFE_GROUPS, JACKKNIFE_SAMPLES_PER_MFP, TELESCOPE_CONTINUE,
                         TELESCOPE_MAX_LEVEL, TELESCOPE_SAMPLES_PER_MFP)
from ..params import C_CAPPED
from .guards import finite_bits
from .medium import (comb_count, extinction, medium_chroma, optical_depth_comb,
                     segment_degenerate)
from .rng import rng_next
from .tracking import ONE3
from .vec import exp_neg3, madd3


@njit(cache=True)
def telescoping_levels(v, n, max_steps):
    """(K, capped): the truncation level for roulette draw v, the largest k with
    v <= TELESCOPE_CONTINUE^k (at most TELESCOPE_MAX_LEVEL), lowered until the n 2^K points
    of level K fit in max_steps."""
    k = 0
    q = TELESCOPE_CONTINUE          # P(K >= k + 1)
    while v <= q and k < TELESCOPE_MAX_LEVEL:
        k += 1
        q *= TELESCOPE_CONTINUE
    capped = v <= q                 # the draw asks for a level past the cap
    while k > 0 and n * (1 << k) > max_steps:
        k -= 1
        capped = True
    return k, capped


@njit(cache=True)
def telescoping_segment(med, o, d, t0, t1, mbar, mu_c, rng, counters, max_steps):
    """Telescoping ("debiasing") estimator of Misso, Li, Burley, Jarosz 2022 ("Unbiased and
    consistent rendering using biased estimators") over nested jittered ray marching.

    Estimate::

        Y_k = exp(-tau_k),  tau_k the jittered comb of n 2^k points (step h / 2^k)
        K ~ P(K >= k) = r^k,  r = TELESCOPE_CONTINUE = 3/8
        T^ = Y_0 + sum_{k=1}^{K} (Y_k - Y_{k-1}) / r^k

    Y_k -> T as k grows, so E[T^] = lim E[Y_k] = T: unbiased. The levels are coupled:
    level k's comb contains level k-1's (every other point), so the differences are small.
    One jitter a_0 = u drives all levels: level k's comb has jitter a_k = frac(2 a_{k-1}),
    uniform whenever a_{k-1} is, and its points (2 j + floor(2 a_{k-1}) + a_k) h_k are level
    k-1's; the new points are the other parity. So each level adds n 2^(k-1) lookups, level K
    costs n 2^K in all, and every Y_k is itself plain jittered ray marching (the marginals
    the telescoping sum needs).

    Constants: n = ceil(TELESCOPE_SAMPLES_PER_MFP mbar L), one point per majorant mean free
    path, as biased ray marching uses. For a continuous extinction the comb error is O(h), so
    E[(Y_k - Y_{k-1})^2] decays like 4^-k while the cost grows like 2^k; a geometric
    P(K >= k) = r^k with 1/4 < r < 1/2 keeps both the variance (sum 4^-k / r^k) and the
    expected cost (n (1 + r / (1 - 2 r)) = 2.5 n for r = 3/8) finite. The paper leaves
    the distribution to the application; Blender Cycles' use of the estimator on shadow
    rays was not in the stored sources this was written from, so these constants are
    volmc's own choice, not Cycles'.

    Random numbers: one for K (drawn first, before any lookup), then the one jitter.
    Single estimates can be negative or above 1 (the differences are weighted by 1 / r^k);
    the mean is unbiased. A non-finite channel (absurd optical depths) returns 0. RGB: every
    level's Y_k,c = exp(-chroma_c tau_k) from the same comb, K and jitter.
    """
    L = t1 - t0
    if segment_degenerate(L, mbar, counters, max_steps, 1):
        return ONE3
    k = medium_chroma(med)
    n = comb_count(TELESCOPE_SAMPLES_PER_MFP * mbar * L)
    v = 1.0 - rng_next(rng)
    capped = n > max_steps
    if capped:
        n = max_steps
    k_max, cut = telescoping_levels(v, n, max_steps)
    if capped or cut:
        counters[C_CAPPED] += 1
    a = rng_next(rng)
    h = L / n
    s = 0.0
    for j in range(n):
        s += extinction(med, madd3(o, d, t0 + (j + a) * h), mbar, counters)
    y = exp_neg3(k, s * h)
    est = y
    w = 1.0
    m = n
    for _ in range(k_max):
        a2 = a + a
        odd = 1 if a2 < 1.0 else 0     # level k-1's points have parity floor(2 a) = 1 - odd
        a = a2 if odd == 1 else a2 - 1.0
        h *= 0.5
        s_new = 0.0
        for j in range(m):
            s_new += extinction(med, madd3(o, d, t0 + (2 * j + odd + a) * h), mbar, counters)
        s += s_new
        m += m
        w *= TELESCOPE_CONTINUE
        y_next = exp_neg3(k, s * h)
        est = (est[0] + (y_next[0] - y[0]) / w, est[1] + (y_next[1] - y[1]) / w,
               est[2] + (y_next[2] - y[2]) / w)
        y = y_next
    return finite_or_zero3(est)


@njit(cache=True)
def jackknife_segment(med, o, d, t0, t1, mbar, mu_c, rng, counters, max_steps):
    """Jackknife ray marching: the standard (grouped) jackknife bias correction of
    exp(-tau_hat) over G = JACKKNIFE_GROUPS independent jittered combs. Biased, but its
    bias is second order in the combs' variance.

    This is NOT the exact estimator of Peters 2025 ("Jackknife transmittance and MIS weight
    estimation", SIGGRAPH Asia 2025): of that paper only its summary was found (it applies
    a UMVU estimator to nearly normally distributed optical-depth estimates from stratified
    jittered sampling, with a bias far below plain ray marching's); its formulas were not.
    What is implemented is the textbook jackknife on the same kind of data::

        X_1..X_G  independent jittered combs of M points each (each unbiased for tau)
        Xbar = mean X_g,  Xbar_(g) = mean of the others (leave one out)
        T^ = G exp(-Xbar) - (G - 1) mean_g exp(-Xbar_(g))
           = exp(-Xbar) (G - ((G - 1) / G) sum_g exp((X_g - Xbar) / (G - 1)))

    If the X_g have variance s^2 and are near normal, E exp(-Xbar) = T exp(s^2 / (2 G)) and
    the correction leaves a relative bias of about -s^4 / (8 G (G - 1)) instead of plain ray
    marching's +s^2 / (2 G): second order. Independent jitters are needed: leaving one point
    out of a single comb would treat the comb's spread of mu along the ray as noise and
    over-correct by a factor of about the comb size.

    Step: M = ceil(JACKKNIFE_SAMPLES_PER_MFP mbar L / G), so G M ~ one lookup per majorant
    mean free path, the cost of biased ray marching. For a continuous extinction s^2 is
    O(h^2) in the comb step h = L / M, so the bias falls like h^4 as the step shrinks (a
    looser majorant or a larger JACKKNIFE_SAMPLES_PER_MFP). G = 2 (T^ = exp(-Xbar)
    (2 - cosh((X_1 - X_2) / 2))): at a fixed budget N = G M the bias goes like
    G^4 / (G (G - 1)) / N^4, smallest at G = 2.

    Estimates are at most exp(-Xbar) and negative when the combs disagree by more than
    2 acosh(2) = 2.63 in optical depth. Random numbers: one jitter per comb. A cap
    (max_steps < G M) shrinks M; max_steps < G returns 1. Both count C_CAPPED. RGB: channel
    c applies the formula to the combs chroma_c X_g (``jackknife_channel``).
    """
    L = t1 - t0
    g = JACKKNIFE_GROUPS
    if segment_degenerate(L, mbar, counters, max_steps, g):
        return ONE3
    m = comb_count(JACKKNIFE_SAMPLES_PER_MFP * mbar * L / g)
    if g * m > max_steps:
        counters[C_CAPPED] += 1
        m = max_steps // g
    xs = np.empty(JACKKNIFE_GROUPS)
    for i in range(g):
        xs[i] = optical_depth_comb(med, o, d, t0, L, m, rng_next(rng), mbar, counters)
    k = medium_chroma(med)
    return (jackknife_channel(xs, k[0]), jackknife_channel(xs, k[1]),
            jackknife_channel(xs, k[2]))


@njit(cache=True)
def jackknife_channel(xs, k):
    """The jackknife estimate of one channel, whose combs are k xs (k its chroma)."""
    g = JACKKNIFE_GROUPS
    total = 0.0
    for i in range(g):
        total += k * xs[i]
    xbar = total / g
    acc = 0.0
    for i in range(g):
        acc += math.exp((k * xs[i] - xbar) / (g - 1))
    pre = math.exp(-xbar)
    if pre == 0.0:
        return 0.0
    est = pre * (g - (g - 1) * acc / g)
    if not finite_bits(est):
        return 0.0
    return est


@njit(cache=True)
def finite_or_zero3(v):
    """Each channel of v, or 0 where it is not finite (absurd optical depths)."""
    return (v[0] if finite_bits(v[0]) else 0.0, v[1] if finite_bits(v[1]) else 0.0,
            v[2] if finite_bits(v[2]) else 0.0)
