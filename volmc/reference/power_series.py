"""Power-series transmittance estimators: unbiased ray marching and the p-series CMF.

Both estimate T = exp(-tau), tau = int_{t0}^{t1} mu(o + t d) dt, by expanding the exponential
around a control optical depth tau_c,

    T = exp(-tau_c) * sum_k (tau_c - tau)^k / k!,

estimating each power (tau_c - tau)^k without bias from k independent estimates of
(tau_c - tau), and randomly truncating the sum (Russian roulette, weights 1 / P(order >= k)).
Any tau_c that is independent of the estimates used for the powers keeps the sum unbiased.

Shared conventions (twins in ``kernels/power_series.h``):

* The segment is [t0, t1] along o + t d (unit d); ``mbar`` >= mu on it is a majorant and
  ``mu_c`` is a control extinction the caller knows: a minorant, the mean, or 0. They only
  set how many terms and lookups are spent; neither needs to be exact for the estimate to
  stay unbiased (p-series estimates are non-negative only if mbar >= mu, though).
* Every density evaluation goes through ``extinction`` (one C_LOOKUPS each); values above the
  majorant are counted in C_OVER_MAJORANT. If an estimate would need more than ``max_steps``
  lookups (or more than the fixed order cap of the U-statistics buffer), the series is cut
  there, C_CAPPED is incremented and the partial (biased) estimate is returned.
* Roulette decisions compare v = 1 - u in (0, 1] against P(order >= k): "continue iff
  v <= P" happens with probability P rounded down to the 2^-24 grid, v is exact in float32
  and float64 alike (the backends part only when v lies within rounding of P), and no single
  draw (u = 0 would be one with "u < P") can drive the order to the cap.
* Degenerate input: t1 <= t0 or mbar <= 0 returns 1 with no lookups (as ratio tracking does);
  max_steps < 1 returns 1 and counts a cap. A product exp(-x) * sum whose exponential
  underflows returns 0 (the transmittance is below the float range); a non-finite sum, only
  reachable with absurd optical depths, also returns 0 rather than NaN.
"""

import math

import numpy as np
from numba import njit

from ..constants import (CMF_FIT_0, CMF_FIT_1, CMF_FIT_2, CMF_FIT_MAX_LAMBDA,  # noqa: F401
                         CMF_GOAL, CMF_RESCALE_BITS, CMF_RESCALE_HI, CMF_RESCALE_LN,
                         CMF_RESCALE_LO, URM_C, URM_K, URM_MAX_ORDER, URM_MEAN_ORDER, URM_P_ZERO)
from ..params import C_CAPPED
from .medium import extinction, optical_depth_comb, segment_degenerate
from .guards import finite_bits
from .rng import rng_next
from .vec import madd3


@njit(cache=True)
def cmf_lookup_budget(lam):
    """Expected lookups of the p-series CMF estimator for Poisson parameter (majorant optical
    depth) lam, as the cubic fit used by Kettunen et al. (2021) to give unbiased ray marching
    an equal budget: ceil(cbrt((0.015 + lam) (0.65 + lam) (60.3 + lam)))."""
    lam = min(lam, CMF_FIT_MAX_LAMBDA)   # (its cube and integer stay in range)
    x = (CMF_FIT_0 + lam) * (CMF_FIT_1 + lam) * (CMF_FIT_2 + lam)
    return int(math.ceil(x ** (1.0 / 3.0)))


@njit(cache=True)
def urm_comb_size(lam):
    """Lookups per optical-depth comb of unbiased ray marching: N_CMF / (1 + E[order]) rounded,
    at least 1, so that the expected total matches the p-series CMF budget."""
    return max(1, int(math.floor(cmf_lookup_budget(lam) / (1.0 + URM_MEAN_ORDER) + 0.5)))


@njit(cache=True)
def cmf_deterministic_terms(lam, limit):
    """1 + the smallest q with Poisson(lam) CMF(q) >= CMF_GOAL (at most limit + 1): the number
    of orders the p-series CMF estimator evaluates before its roulette starts. The pmf is
    accumulated in the log domain so exp(-lam) underflowing at large lam does not stall it."""
    log_p = -lam
    cmf = math.exp(log_p)
    log_lam = math.log(lam) if lam > 0.0 else 0.0
    q = 0
    while cmf < CMF_GOAL and q < limit:
        q += 1
        log_p += log_lam - math.log(q)
        cmf += math.exp(log_p)
    return q + 1


@njit(cache=True)
def urm_order_ratio(k):
    """P(N >= k) / P(N >= k - 1) of the aggressive roulette, k >= 1: 1 - p_Z to leave order 0,
    then 1 up to order K, then min(1, c / k). Sampling and weights both use it."""
    if k == 1:
        return 1.0 - URM_P_ZERO
    if k <= URM_K:
        return 1.0
    return min(1.0, URM_C / k)


@njit(cache=True)
def urm_series(x0, ys, n):
    """exp(-x0) sum_{k=0}^{n} E_k / (k! P(N >= k)), E_k the elementary symmetric mean of order
    k of ys[0..n-1] (E_0 = 1): the unbiased ray-marching estimate for control x0, order n and
    differences ys[i] = x0 - X_{i+1}. Returns 0 if exp(-x0) underflows or the sum is not
    finite.

    E_k is updated online, E_k += (k / i)(E_{k-1} y_i - E_k) for k = i..1 as y_i arrives:
    O(n^2), and each update is a convex blend, so it neither overflows nor cancels the way
    the raw symmetric polynomials (up to C(n, k) times larger) would."""
    e = np.zeros(n + 1)
    e[0] = 1.0
    for i in range(1, n + 1):
        y = ys[i - 1]
        inv_i = 1.0 / i
        for k in range(i, 0, -1):
            e[k] += (k * inv_i) * (e[k - 1] * y - e[k])
    # w_k = 1 / (k! P(N >= k)) as a running product of the continuation ratios.
    s = 1.0
    w = 1.0
    for k in range(1, n + 1):
        w /= k * urm_order_ratio(k)
        s += e[k] * w
    pre = math.exp(-x0)
    if pre == 0.0:
        return 0.0
    est = pre * s
    if not finite_bits(est):
        return 0.0
    return est


@njit(cache=True)
def unbiased_raymarch_segment(med, o, d, t0, t1, mbar, mu_c, rng, counters, max_steps):
    """Unbiased ray marching (Kettunen, d'Eon, Pantaleoni, Novak 2021, "An unbiased
    ray-marching transmittance estimator", their final, recommended estimator).

    Estimate::

        N ~ aggressive roulette:  P(N >= k) = Q_k,  Q_0 = 1,  Q_1 = Q_2 = 1 - p_Z,
                                  Q_k = Q_{k-1} min(1, c / k) for k > 2
        X_0, ..., X_N  independent jittered equidistant combs of M lookups each
        Y_i = X_0 - X_i,  E_k = elementary symmetric mean of order k of Y_1..Y_N
        T^ = exp(-X_0) * sum_{k=0}^{N} E_k / (k! Q_k)

    Given X_0 and N, E_k is an unbiased estimate of (X_0 - tau)^k (a U-statistic: the mean
    of all products of k distinct Y_i, which reuses every comb in every order instead of one
    comb per factor), so the sum is the roulette estimate of
    exp(-X_0) sum_k (X_0 - tau)^k / k! = exp(-tau). The control X_0 is the online "mean
    density" estimate of the paper: the zeroth order alone is plain jittered ray marching
    exp(-X_0), and the rarely sampled higher orders remove its Jensen bias.

    Parameters (the paper's defaults):

    * p_Z = 0.9, K = 2, c = 2 (URM_P_ZERO, URM_K, URM_C): 90 % of estimates are order 0;
      the rest go to order >= 2 and continue with probability 2 / k. E[N] = 0.31945. For
      k >= 1 the weight 1 / (k! Q_k) is 10 / 2^(k-1).
    * M = max(1, round(N_CMF(tau_bar) / (1 + E[N]))), tau_bar = mbar (t1 - t0) and N_CMF the
      fit of the p-series CMF estimator's expected lookups (``cmf_lookup_budget``): the
      paper sizes the combs so the expected cost equals that estimator's for the same
      majorant. Lookups per estimate therefore grow with the majorant, not with mu.
    * mu_c is not used. The paper's control is the online X_0, which beats any constant:
      it is exact when mu is constant along the ray (all X_i are then exactly tau, so every
      Y_i = 0 and T^ = exp(-tau) whatever N and the jitters are: zero variance, tight or
      loose majorant), and otherwise it follows this ray's actual mean. Nor can mu_c shrink
      the comb: what the comb needs is the spread of mu, which a mean does not bound (a
      narrow deep Gaussian hole given its mean would get M = 3 instead of 7: measured,
      10^7 times the variance for 2.3x fewer lookups).
    * The elementary means are accumulated online (``urm_series``): O(N^2) flops, buffers of
      URM_MAX_ORDER (+ 1) values, which the order never reaches with these parameters.

    Expected lookups: M (1 + E[N]) = 1.31945 M, about N_CMF(tau_bar): 1.3 (M = 1) for
    tau_bar -> 0, 5.3 (M = 4) at 1, 9.2 (M = 7) at 3, 19.8 (M = 15) at 10; order-0 estimates
    cost exactly M.
    Random numbers: one for the order, then one jitter per comb.

    The estimate is negative when an odd-order E_k outweighs the rest (the expansion
    alternates in sign when X_0 < tau); that is expected, and the mean is unbiased.
    Returns the estimate of T.
    """
    L = t1 - t0
    if segment_degenerate(L, mbar, counters, max_steps, 1):
        return 1.0
    m = urm_comb_size(mbar * L)
    # The order is drawn before any lookup, so it is independent of the combs (and the
    # whole cost is known up front).
    v = 1.0 - rng_next(rng)
    n = 0
    q = 1.0
    capped = False
    while True:
        q_next = q * urm_order_ratio(n + 1)
        if not (v <= q_next):
            break
        if n == URM_MAX_ORDER:
            capped = True
            break
        n += 1
        q = q_next
    if m > max_steps // (n + 1):   # m (n + 1) > max_steps, as the kernel's int32 can test it
        capped = True
        if m > max_steps:
            m = max_steps
            n = 0
        else:
            n = max_steps // m - 1
    if capped:
        counters[C_CAPPED] += 1
    x0 = optical_depth_comb(med, o, d, t0, L, m, rng_next(rng), mbar, counters)
    ys = np.empty(URM_MAX_ORDER)
    for i in range(n):
        ys[i] = x0 - optical_depth_comb(med, o, d, t0, L, m, rng_next(rng), mbar, counters)
    return urm_series(x0, ys, n)


@njit(cache=True)
def power_series_segment(med, o, d, t0, t1, mbar, mu_c, rng, counters, max_steps):
    """P-series CMF estimator (Georgiev, Misso, Hachisuka, Nowrouzezahrai, Krivanek, Jarosz
    2019, "Integral formulations of volumetric transmittance", the power-series formulation
    with the CMF-based roulette).

    Expansion around the majorant optical depth tau_bar = mbar (t1 - t0)::

        T = exp(-tau_bar) sum_k (tau_bar - tau)^k / k!
        term_k^ = exp(-tau_bar) prod_{j=1}^{k} Y_j / j,   Y_j = (mbar - mu(x_j)) (t1 - t0),
                  x_j uniform on [t0, t1], one new x_j per order (independent factors)
        T^ = sum_{k=0}^{N} term_k^ / P(N >= k)

    Orders k = 1..n are always evaluated, n = 1 + the CMF_GOAL (0.99) quantile of a Poisson
    distribution with mean LAMBDA = max(mbar - mu_c, 0) (t1 - t0) (see Control below): when
    tau_bar - tau = LAMBDA, E[term_k] / T is exactly the Poisson pmf LAMBDA^k e^-LAMBDA / k!,
    so the deterministic part holds 99 % of T. Past n, order k is reached with conditional
    probability min(1, LAMBDA / k), the pmf ratio, so P(N >= k) follows the Poisson tail.

    Variant: the power-series estimators in Georgiev et al.'s Fig. 1 are "p-series cumulative"
    (roulette on the running weight) and "p-series CMF" (this one). In that equal-lookup render
    the CMF variant has the best efficiency of all four estimators shown: RMSE 1.8e-2 in
    3163 s, against cumulative 1.7e-2 in 4139 s, ratio tracking 2.4e-2 in 5434 s and
    next-flight 4.3e-2 in 5608 s (1 / (RMSE^2 time) = 0.98, 0.84, 0.32, 0.10), because its
    cost is fixed by LAMBDA rather than by the running weight. Kettunen et al. (2021) compare
    against it and give unbiased ray marching its lookup budget. So this is the one
    implemented.

    Control: Georgiev et al. expand around the majorant and use LAMBDA = tau_bar (mu_c = 0
    here reproduces that exactly). A constant control mu_c leaves the expansion unchanged
    (residual-tracking form: exp(-tau_c) exp(-(tau_bar - tau_c)) sum (tau_bar - tau)^k / k!
    is the same series), so the given mu_c only sets the Poisson parameter
    LAMBDA = max(mbar - mu_c, 0) (t1 - t0): an upper bound of tau_bar - tau for a minorant, its
    value for the mean, and tau_bar - tau is exactly what sizes the terms. Smaller LAMBDA means
    fewer deterministic orders and faster roulette at about the same variance (measured: the
    same variance with 2.3x fewer lookups on a Gaussian hole given its mean). The estimate is
    unbiased for any LAMBDA > 0; LAMBDA = 0 (mu_c >= mbar) is correct only when mu = mbar.

    Numerics: exp(-tau_bar) is split evenly over the deterministic orders (factor
    g = exp(-tau_bar / n) per order, summed Horner-style), so it never underflows alone. The
    partial products still grow like e^(LAMBDA / e) before the g's bring them down, past
    float32 from LAMBDA ~ 240 on (a majorant segment of optical depth 500: NaN estimates
    once an inf met a zero factor). So the running sum and product are rescaled together by
    exact powers of two (``cmf_rescale``) whenever the sum leaves [2^-64, 2^64], the
    exponent counted apart and applied at the end (``cmf_scaled_result``); where nothing
    leaves that range the numbers are those of the plain sums bit for bit. A zero factor
    (mu = mbar at a sample) makes every later term zero, so the walk stops there.

    Expected lookups: n + sum_{k > n} P(N >= k): 1 at LAMBDA = 0, 4.1 at 0.5, 5.2 at 1,
    9.4 at 3, 19.9 at 10, 45.8 at 30 (``cmf_lookup_budget`` fits this); fewer when a factor
    is zero (1 for a constant medium under a tight majorant).
    Random numbers: one for the whole roulette tail (drawn first), one position per order.

    With mbar >= mu every factor is >= 0, so the estimate is non-negative; a majorant that is
    too low (counted in C_OVER_MAJORANT) gives negative factors and can give negative
    estimates. Returns the estimate of T.
    """
    L = t1 - t0
    if segment_degenerate(L, mbar, counters, max_steps, 1):
        return 1.0
    tau_bar = mbar * L
    lam = max(mbar - max(mu_c, 0.0), 0.0) * L
    n_det = cmf_deterministic_terms(lam, max_steps)
    if n_det > max_steps:
        # The CMF goal lies past the step cap: the estimate is cut short, and counted here,
        # since g below may underflow (tau_bar / n_det > 745) and end the walk at its first
        # order, before it reaches the cap (a voxel of 2e8 gave T = 0, uncounted).
        counters[C_CAPPED] += 1
    v = 1.0 - rng_next(rng)
    g = math.exp(-tau_bar / n_det)
    acc = 1.0      # sum_{j <= k} V_j g^(k - j); equals the estimate once k = n_det
    prod = 1.0     # V_k = g^min(k, n_det) prod_{j <= k} Y_j / j
    e = 0          # both are 2^(-CMF_RESCALE_BITS e) times their value
    k = 0
    while k < n_det:
        if k == max_steps:   # (counted above)
            return cmf_scaled_result(acc, e, n_det - k, tau_bar / n_det)
        k += 1
        x = t0 + rng_next(rng) * L
        y = (mbar - extinction(med, madd3(o, d, x), mbar, counters)) * L
        prod *= g * y / k
        acc = acc * g + prod
        if prod == 0.0:
            return cmf_scaled_result(acc, e, n_det - k, tau_bar / n_det)
        acc, prod, e = cmf_rescale(acc, prod, e)
    q = 1.0
    while True:
        q *= min(1.0, lam / (k + 1))
        if not (v <= q):
            break
        if k == max_steps:
            counters[C_CAPPED] += 1
            break
        k += 1
        x = t0 + rng_next(rng) * L
        y = (mbar - extinction(med, madd3(o, d, x), mbar, counters)) * L
        prod *= y / k
        acc += prod / q
        if prod == 0.0:
            break
        acc, prod, e = cmf_rescale(acc, prod, e)
    acc = math.ldexp(acc, CMF_RESCALE_BITS * e)
    if not finite_bits(acc):
        return 0.0
    return acc


@njit(cache=True, inline="always")
def cmf_rescale(acc, prod, e):
    """(acc, prod, e) with acc and prod multiplied by the same exact power of two, and e
    counting it, when |acc| leaves [CMF_RESCALE_LO, CMF_RESCALE_HI] (0 stays 0): the sums are
    linear in both, so a common factor carries through to the end."""
    a = abs(acc)   # (negative only under a majorant too low)
    if a > CMF_RESCALE_HI:
        return acc * CMF_RESCALE_LO, prod * CMF_RESCALE_LO, e + 1
    if 0.0 < a < CMF_RESCALE_LO:
        return acc * CMF_RESCALE_HI, prod * CMF_RESCALE_HI, e - 1
    return acc, prod, e


@njit(cache=True, inline="always")
def cmf_scaled_result(acc, e, left, tau_per_order):
    """acc 2^(CMF_RESCALE_BITS e) g^left, g = exp(-tau_per_order): the estimate of a walk
    that stopped ``left`` deterministic orders early, in the log domain (each factor alone
    may be out of range where the product is not); 0 for a non-finite acc."""
    if acc == 0.0 or not finite_bits(acc):
        return 0.0
    # (negative only under a majorant too low, counted in C_OVER_MAJORANT)
    return math.copysign(math.exp(math.log(abs(acc)) + e * CMF_RESCALE_LN -
                                  left * tau_per_order), acc)
