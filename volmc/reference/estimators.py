"""Transmittance estimators on a common interface, for comparison and benchmarking.

Every estimator estimates T = exp(-tau), tau = integral of mu over [t0, t1] along o + t d
(unit d), where mu comes from ``extinction(med, grid, o, d, t, counters)`` (a grid or an
analytic 1-D profile, see extinction.py; each evaluation is one counted lookup). Common
arguments:

* ``mbar``: a majorant, mbar >= mu on the segment (1/world unit);
* ``mu_c``: a control / minorant, 0 <= mu_c <= mu on the segment (0 when unknown);
* ``rng``: the caller's random stream; ``counters``: per-caller counters;
* ``max_steps``: cap on tentative collisions (or comb points); a capped estimate is counted
  in counters[C_CAPPED] and returned as it stands.

The twins in kernels/estimators.h have the same names and arguments (float32).
Unbiased estimators here: track-length, ratio tracking, residual ratio tracking,
next-flight ratio tracking; ``transmittance_analytic`` is exact for a homogeneous segment
(mbar == mu_c) and undefined otherwise; ``transmittance_biased_raymarch`` is biased. The
power-series estimators (p-series CMF of Georgiev et al. 2019, unbiased ray marching of
Kettunen et al. 2021) are in power_series.py; ESTIMATORS below registers all of them.
"""

import math

import numpy as np
from numba import njit, prange

from ..constants import TR_RR_THRESHOLD
from ..params import C_CAPPED, N_COUNTERS
from .extinction import lookup
from .power_series import transmittance_power_series, transmittance_unbiased_raymarch
from .rng import STREAM_TEST, rng_new, rng_next



@njit(cache=True, inline="always")
def transmittance_roulette(T, rng):
    """Russian roulette on a running transmittance weight. Returns (alive, T).

    Once |T| < TR_RR_THRESHOLD the walk survives with probability q = |T| / TR_RR_THRESHOLD
    and carries T / q = +-TR_RR_THRESHOLD, else it ends with T = 0: E[T] is unchanged
    (unbiased), and T == 0 ends the walk at once. Dense media (HARD_CASES 10: majorant optical
    depth 1e6) then cost a few lookups per shadow ray instead of the whole walk. The threshold
    is low enough that the variance it adds (at most TR_RR_THRESHOLD^2 per estimate) is
    invisible in the closed-form variance of ratio tracking."""
    a = abs(T)
    if not a < TR_RR_THRESHOLD:
        return True, T
    if a == 0.0 or rng_next(rng) * TR_RR_THRESHOLD >= a:
        return False, 0.0
    return True, TR_RR_THRESHOLD if T > 0.0 else -TR_RR_THRESHOLD


# Guard "local distances" (HARD_CASES 11): every tracking loop below accumulates the distance
# s from the segment start t0, never t itself, so a far ray origin (t0 = 1e5 with a majorant of
# 1e3: t + dt == t in float32) cannot stall the walk; lookups are at t0 + s.


@njit(cache=True)
def transmittance_analytic(med, grid, o, d, t0, t1, mbar, mu_c, rng, counters, max_steps):
    """Homogeneous segment (mbar == mu_c == mu): T = exp(-mu (t1 - t0)), no lookups."""
    return math.exp(-mbar * max(t1 - t0, 0.0))


@njit(cache=True)
def transmittance_track_length(med, grid, o, d, t0, t1, mbar, mu_c, rng, counters, max_steps):
    """Track-length estimator (delta tracking): 1 if the walk passes t1, 0 at the first real
    collision. Tentative collisions at rate mbar, accepted with probability mu / mbar.
    Mean lookups <= mbar (t1 - t0). Variance T (1 - T)."""
    if mbar <= 0.0:
        return 1.0
    inv = 1.0 / mbar
    L = t1 - t0
    s = 0.0
    for _ in range(max_steps):
        s -= math.log1p(-rng_next(rng)) * inv
        if s >= L:
            return 1.0
        if rng_next(rng) * mbar < lookup(med, grid, o, d, t0 + s, counters, mbar):
            return 0.0
    counters[C_CAPPED] += 1
    return 0.0


@njit(cache=True)
def transmittance_residual_ratio(med, grid, o, d, t0, t1, mbar, mu_c, rng, counters,
                                 max_steps):
    """Residual ratio tracking (Novak, Selle, Jarosz 2014) with a constant control mu_c:
    T = exp(-mu_c L) prod_i (1 - (mu(x_i) - mu_c) / mbar_r), tentative collisions at the
    residual majorant rate mbar_r = mbar - mu_c >= mu - mu_c >= 0.
    Mean lookups = (mbar - mu_c) L: the control's share of tau costs nothing."""
    L = max(t1 - t0, 0.0)
    Tc = math.exp(-mu_c * L)
    mr = mbar - mu_c
    if mr <= 0.0:
        return Tc
    inv = 1.0 / mr
    T = Tc
    s = 0.0
    for _ in range(max_steps):
        s -= math.log1p(-rng_next(rng)) * inv
        if s >= L:
            return T
        T *= 1.0 - (lookup(med, grid, o, d, t0 + s, counters, mbar) - mu_c) / mr
        alive, T = transmittance_roulette(T, rng)
        if not alive:
            return T
    counters[C_CAPPED] += 1
    return T


@njit(cache=True)
def transmittance_ratio_tracking(med, grid, o, d, t0, t1, mbar, mu_c, rng, counters, max_steps):
    """Ratio tracking (Cramer 1978; Novak, Selle, Jarosz 2014):
    T = prod_i (1 - mu(x_i) / mbar) over tentative collisions at rate mbar.
    Mean lookups = mbar (t1 - t0). Homogeneous variance: e^{-2 s L}(e^{s^2 L / mbar} - 1).
    It is residual ratio tracking with a zero control (mu_c is ignored): exp(-0 L) = 1 and
    mu - 0 = mu exactly, so the same walk with the same lookups and estimates."""
    return transmittance_residual_ratio(med, grid, o, d, t0, t1, mbar, 0.0, rng, counters,
                                        max_steps)


@njit(cache=True)
def transmittance_next_flight(med, grid, o, d, t0, t1, mbar, mu_c, rng, counters, max_steps):
    """Next-flight ratio tracking (see Novak et al. 2018's report; Georgiev et al. 2019):
    each vertex of a ratio-tracking walk adds the probability that the next flight passes t1,
    T = sum_{i>=0} w_i exp(-mbar (t1 - t_i)), w_0 = 1 at t_0 = t0,
    w_i = w_{i-1} (1 - mu(t_i) / mbar). The same walk as ratio tracking (same lookups), with
    the final 0/1 escape test replaced by its expectation: lower variance."""
    if mbar <= 0.0:
        return 1.0
    inv = 1.0 / mbar
    w = 1.0
    L = t1 - t0
    s = 0.0
    T = math.exp(-mbar * max(L, 0.0))
    for _ in range(max_steps):
        s -= math.log1p(-rng_next(rng)) * inv
        if s >= L:
            return T
        w *= 1.0 - lookup(med, grid, o, d, t0 + s, counters, mbar) / mbar
        alive, w = transmittance_roulette(w, rng)
        if not alive:
            return T
        T += w * math.exp(-mbar * (L - s))
    counters[C_CAPPED] += 1
    return T


@njit(cache=True)
def transmittance_biased_raymarch(med, grid, o, d, t0, t1, mbar, mu_c, rng, counters,
                                  max_steps, samples_per_mfp=1.0):
    """Biased ray marching (a reference point, NOT unbiased): a jittered comb of
    n = ceil(samples_per_mfp * mbar L) equidistant points estimates tau without bias, but
    exp(-tau_hat) overestimates T (Jensen). The bias shrinks as the step shrinks.
    An empty segment (mbar <= 0, so mu = 0, or zero length) returns 1 with no lookup, as
    every other estimator does (HARD_CASES 8: no lookups in empty majorant cells)."""
    L = max(t1 - t0, 0.0)
    if mbar <= 0.0 or L <= 0.0:
        return 1.0
    n = max(1, int(math.ceil(samples_per_mfp * mbar * L)))
    if n > max_steps:
        counters[C_CAPPED] += 1
        n = max_steps
    dt = L / n
    u = rng_next(rng)
    tau = 0.0
    for j in range(n):
        tau += lookup(med, grid, o, d, t0 + (j + u) * dt, counters, mbar)
    return math.exp(-tau * dt)


EST_ANALYTIC, EST_TRACK_LENGTH, EST_RATIO, EST_RESIDUAL_RATIO, EST_NEXT_FLIGHT, \
    EST_BIASED_RAYMARCH, EST_POWER_SERIES, EST_UNBIASED_RAYMARCH = range(8)

#: The registry, written once: name -> (id, kernel function in kernels/estimators.h,
#: unbiased?, needs a homogeneous segment?). The names are the values of render.transmittance
#: and of `volmc bench transmittance --estimators`.
ESTIMATORS = {
    "analytic": (EST_ANALYTIC, "transmittance_analytic", True, True),
    "track_length": (EST_TRACK_LENGTH, "transmittance_track_length", True, False),
    "ratio": (EST_RATIO, "transmittance_ratio_tracking", True, False),
    "residual_ratio": (EST_RESIDUAL_RATIO, "transmittance_residual_ratio", True, False),
    "next_flight": (EST_NEXT_FLIGHT, "transmittance_next_flight", True, False),
    "biased_raymarch": (EST_BIASED_RAYMARCH, "transmittance_biased_raymarch", False, False),
    "power_series": (EST_POWER_SERIES, "transmittance_power_series", True, False),
    "unbiased_raymarch": (EST_UNBIASED_RAYMARCH, "transmittance_unbiased_raymarch", True, False),
}
#: Estimators whose single estimates can be negative (their mean is still T).
SIGNED = ("unbiased_raymarch",)


@njit(cache=True)
def estimate_one(est, med, grid, o, d, t0, t1, mbar, mu_c, rng, cnt, max_steps, extra):
    """Run estimator ``est`` (an id of ESTIMATORS); ``extra`` is biased ray marching's
    samples per majorant mean free path."""
    if est == EST_ANALYTIC:
        return transmittance_analytic(med, grid, o, d, t0, t1, mbar, mu_c, rng, cnt, max_steps)
    if est == EST_TRACK_LENGTH:
        return transmittance_track_length(med, grid, o, d, t0, t1, mbar, mu_c, rng, cnt,
                                          max_steps)
    if est == EST_RATIO:
        return transmittance_ratio_tracking(med, grid, o, d, t0, t1, mbar, mu_c, rng, cnt,
                                            max_steps)
    if est == EST_RESIDUAL_RATIO:
        return transmittance_residual_ratio(med, grid, o, d, t0, t1, mbar, mu_c, rng, cnt,
                                            max_steps)
    if est == EST_NEXT_FLIGHT:
        return transmittance_next_flight(med, grid, o, d, t0, t1, mbar, mu_c, rng, cnt,
                                         max_steps)
    if est == EST_BIASED_RAYMARCH:
        return transmittance_biased_raymarch(med, grid, o, d, t0, t1, mbar, mu_c, rng, cnt,
                                             max_steps, extra)
    if est == EST_POWER_SERIES:
        return transmittance_power_series(med, grid, o, d, t0, t1, mbar, mu_c, rng, cnt,
                                          max_steps)
    if est == EST_UNBIASED_RAYMARCH:
        return transmittance_unbiased_raymarch(med, grid, o, d, t0, t1, mbar, mu_c, rng, cnt,
                                               max_steps)
    raise ValueError("unknown estimator id")


@njit(cache=True, parallel=True)
def estimate_batch(est, med, grid, rays, bounds, n_per_ray, seed, sample_offset, max_steps,
                   extra):
    """n_per_ray estimates for each ray (rows of ``rays``: o(3), d(3), t0, t1, pad; rows of
    ``med``: the ray's extinction source; rows of ``bounds``: mbar, mu_c). Estimate i uses ray i // n_per_ray, sample index
    sample_offset + i % n_per_ray on STREAM_TEST, like kernels/estimators.cl.
    Returns (estimates [n], counters [n, N_COUNTERS])."""
    n = rays.shape[0] * n_per_ray
    out = np.empty(n)
    counters = np.zeros((n, N_COUNTERS), np.int64)
    for i in prange(n):
        r = i // n_per_ray
        rng = rng_new(seed, r, sample_offset + i % n_per_ray, STREAM_TEST)
        o = (rays[r, 0], rays[r, 1], rays[r, 2])
        d = (rays[r, 3], rays[r, 4], rays[r, 5])
        out[i] = estimate_one(est, med[r], grid, o, d, rays[r, 6], rays[r, 7], bounds[r, 0],
                               bounds[r, 1], rng, counters[i], max_steps, extra)
    return out, counters
