"""Transmittance estimators on one interface, for shadow rays and the estimator benchmark.

Twin of ``kernels/estimators.h``. Every estimator estimates T = exp(-tau) along o + t d over
[t0, t1] (unit d, inside the medium box), tau the integral of the medium's extinction, with
the signature ``transmittance_<name>(med, o, d, t0, t1, rng, counters, max_steps)``: ``med``
a ``MediumData`` (medium.py), whose majorant segments give every bound an estimator uses;
``rng`` the caller's stream; ``counters`` the caller's counters; ``max_steps`` the step cap
(a capped estimate is counted in counters[C_CAPPED] and returned as it stands). The registry
of names and properties is ``volmc/techniques.py``.

Two families, each run by one loop over the majorant segments:

* **Tracking estimators** -- track length, ratio, residual ratio and next-flight tracking --
  are techniques of the one tracking loop (tracking.py).
* **Per-segment estimators** -- ``transmittance_analytic`` (exp(-sigma_maj L), exact only on
  homogeneous segments), biased ray marching, the power series (power_series.py) and the
  telescoping and jackknife ray marching (debiasing.py) -- run
  on each segment in turn with its bounds (``transmittance_by_segments``); the product of
  independent unbiased per-segment estimates is unbiased. Between segments the running
  product plays transmittance roulette on its largest channel (``segment_roulette``).
  The analytic, ray-marching, telescoping and jackknife estimates are RGB (channel c's
  optical depth is chroma_c tau, from the same lookups); the power series are grey (the
  schema keeps them from colour-dependent media) and count for all three channels.

Either way a homogeneous segment (sigma_min == sigma_maj) contributes its exact
exp(-sigma_maj L), with no lookup and no random number: a homogeneous medium always gets the
analytic transmittance, whichever estimator is chosen.
"""

import numpy as np
from numba import njit, prange

from ..constants import (ESTIMATOR_ANALYTIC, ESTIMATOR_AUTO, ESTIMATOR_AUTO_SHADOW,
                         ESTIMATOR_BIASED_RAYMARCH, ESTIMATOR_JACKKNIFE,
                         ESTIMATOR_NEXT_FLIGHT, ESTIMATOR_POWER_SERIES, ESTIMATOR_RATIO,
                         ESTIMATOR_RESIDUAL_RATIO, ESTIMATOR_TELESCOPING,
                         ESTIMATOR_TRACK_LENGTH, ESTIMATOR_UNBIASED_RAYMARCH,
                         RAYMARCH_SAMPLES_PER_MFP, SEGMENT_ANALYTIC, SEGMENT_BIASED_RAYMARCH,
                         SEGMENT_JACKKNIFE, SEGMENT_POWER_SERIES, SEGMENT_TELESCOPING,
                         SEGMENT_UNBIASED_RAYMARCH, SPECTRAL_GREY, STREAM_TEST, TRACK_AUTO,
                         TRACK_LENGTH,
                         TRACK_NEXT_FLIGHT, TRACK_RATIO, TRACK_RESIDUAL_RATIO)
from ..params import C_CAPPED, N_COUNTERS
from .medium import (MediumData, new_iter, comb_count, majorant_iter_init,
                     majorant_next,
                     medium_chroma, no_field_arrays, optical_depth_comb)
from .debiasing import jackknife_segment, telescoping_segment
from .power_series import power_series_segment, unbiased_raymarch_segment
from .rng import rng_new, rng_next
from .tracking import EMIS_PLAIN, ONE3, track, transmittance_roulette
from .vec import exp_neg3, madd3, max3, mul3

# The estimators pass their technique as int(TRACK_*) and int(SEGMENT_*): Numba types a global
# constant as a literal and compiles a callee once per literal value it is called with, so
# track, tracked_transmittance, transmittance_by_segments and segment_estimate compiled 5 to
# 7 times each; as plain integers they compile once and branch at run time.


@njit(cache=True)
def biased_raymarch_segment(med, o, d, t0, t1, mbar, mu_c, rng, counters, max_steps):
    """Biased ray marching over one segment (a reference point, NOT unbiased): a jittered comb
    of n = ceil(RAYMARCH_SAMPLES_PER_MFP * mbar L) equidistant points estimates tau without
    bias, but exp(-tau_hat) overestimates T (Jensen); the bias shrinks as the step shrinks (a
    looser majorant gives a finer comb). An empty segment (mbar <= 0, or zero length) gives
    1 with no lookup. RGB: exp(-chroma_c tau_hat)."""
    L = max(t1 - t0, 0.0)
    if mbar <= 0.0 or L <= 0.0:
        return ONE3
    n = comb_count(RAYMARCH_SAMPLES_PER_MFP * mbar * L)
    if n > max_steps:
        counters[C_CAPPED] += 1
        n = max_steps
    return exp_neg3(medium_chroma(med),
                    optical_depth_comb(med, o, d, t0, L, n, rng_next(rng), mbar, counters))


@njit(cache=True)
def segment_estimate(kind, med, o, d, t0, t1, s_maj, s_min, rng, counters, max_steps):
    """One per-segment estimate of kind SEGMENT_* over [t0, t1] with bounds s_maj, s_min:
    RGB (the power series' grey estimate in every channel)."""
    if kind == SEGMENT_BIASED_RAYMARCH:
        return biased_raymarch_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters,
                                       max_steps)
    if kind == SEGMENT_POWER_SERIES:
        T = power_series_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters, max_steps)
        return (T, T, T)
    if kind == SEGMENT_UNBIASED_RAYMARCH:
        T = unbiased_raymarch_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters,
                                      max_steps)
        return (T, T, T)
    if kind == SEGMENT_TELESCOPING:
        return telescoping_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters, max_steps)
    if kind == SEGMENT_JACKKNIFE:
        return jackknife_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters, max_steps)
    return exp_neg3(medium_chroma(med), s_maj * (t1 - t0))   # SEGMENT_ANALYTIC


@njit(cache=True)
def segment_roulette(T, rng):
    """``transmittance_roulette`` on an RGB weight by its largest |channel| a (the decision
    and the random numbers of the grey roulette on a): a survivor's channels are scaled by
    TR_RR_THRESHOLD / a, as T_c / a x TR_RR_THRESHOLD, so a grey weight becomes exactly the
    grey roulette's +-TR_RR_THRESHOLD."""
    a = max3((abs(T[0]), abs(T[1]), abs(T[2])))
    alive, s = transmittance_roulette(a, rng)   # a no-op while a >= TR_RR_THRESHOLD
    if not alive:
        return False, (0.0, 0.0, 0.0)
    if s == a:
        return True, T
    return True, ((T[0] / a) * s, (T[1] / a) * s, (T[2] / a) * s)


@njit(cache=True)
def transmittance_by_segments(med, o, d, t0, t1, kind, rng, counters, max_steps):
    """Product over the majorant segments of [t0, t1] of per-segment estimates of ``kind``
    (exact on homogeneous segments, exp(-chroma_c sigma L)), RGB, with transmittance roulette
    on the largest channel between segments. Guard "local distances": the walk starts at
    o + t0 d."""
    o = madd3(o, d, t0)
    it = new_iter(med)
    majorant_iter_init(it, med, o, d, 0.0, t1 - t0)
    k = medium_chroma(med)
    T = ONE3
    while True:
        ok, ta, tb, s_maj, s_min, _ = majorant_next(it, med)
        if not ok:
            return T
        alive, T = segment_roulette(T, rng)
        if not alive:
            return T
        if s_min == s_maj:
            T = mul3(T, exp_neg3(k, s_maj * (tb - ta)))
            continue
        T = mul3(T, segment_estimate(kind, med, o, d, ta, tb, s_maj, s_min, rng, counters,
                                     max_steps))


@njit(cache=True)
def transmittance_analytic(med, o, d, t0, t1, rng, counters, max_steps):
    """exp(-sigma_maj L) on every segment: exact where the segments are homogeneous
    (sigma_maj is the extinction there), no lookups; not an estimator for varying media."""
    return transmittance_by_segments(med, o, d, t0, t1, int(SEGMENT_ANALYTIC), rng, counters,
                                     max_steps)


@njit(cache=True)
def tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps, technique):
    """The transmittance estimate of the tracking loop with ``technique``. Track length uses
    each segment's minorant as control (decomposition tracking): the same 0/1 decisions as
    delta tracking for the same random numbers, without the lookups the control decides."""
    return track(med, o, d, t0, t1, technique,
                 technique == TRACK_LENGTH or technique == TRACK_AUTO, ONE3, -1, EMIS_PLAIN,
                 rng, counters, max_steps)[2]


@njit(cache=True)
def transmittance_track_length(med, o, d, t0, t1, rng, counters, max_steps):
    """Track-length estimator: the free-flight walk (decomposition tracking, the same decisions
    as delta tracking), 1 if it escapes past t1, 0 at its first real collision; homogeneous
    segments contribute exp(-sigma L). Variance at most T (1 - T)."""
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps, int(TRACK_LENGTH))


@njit(cache=True)
def transmittance_ratio_tracking(med, o, d, t0, t1, rng, counters, max_steps):
    """Ratio tracking: T = prod (1 - mu(x_i) / sigma_maj) over tentative collisions at each
    segment's majorant rate. Mean lookups = majorant optical depth (less with roulette).
    Homogeneous variance (extinction s, majorant m, length L): e^{-2 s L}(e^{s^2 L / m} - 1)."""
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps, int(TRACK_RATIO))


@njit(cache=True)
def transmittance_residual_ratio(med, o, d, t0, t1, rng, counters, max_steps):
    """Residual ratio tracking with each segment's minorant mu_c as control:
    exp(-mu_c L) prod (1 - (mu(x_i) - mu_c) / (sigma_maj - mu_c)), collisions at the residual
    rate; the control's share of tau costs no lookup."""
    return tracked_transmittance(med, o, d, t0, t1,
                                 rng, counters, max_steps, int(TRACK_RESIDUAL_RATIO))


@njit(cache=True)
def transmittance_next_flight(med, o, d, t0, t1, rng, counters, max_steps):
    """Next-flight ratio tracking: per segment, sum_i w_i exp(-sigma_maj (t_max - t_i)) over
    the walk's vertices (the same lookups as ratio tracking, the final 0/1 escape replaced by
    its expectation). In empty space under a majorant m its variance is (1 - e^{-2 m L}) / 2:
    it needs a tight majorant."""
    return tracked_transmittance(med, o, d, t0, t1,
                                 rng, counters, max_steps, int(TRACK_NEXT_FLIGHT))


@njit(cache=True)
def auto_alone_kind(med):
    """The per-segment estimator ``transmittance_auto`` runs on every varying segment:
    unbiased ray marching in a grey medium, telescoping in a colour-dependent one (the power
    series are grey)."""
    return SEGMENT_UNBIASED_RAYMARCH if med[0].m.spectral == SPECTRAL_GREY else SEGMENT_TELESCOPING


@njit(cache=True)
def transmittance_auto(med, o, d, t0, t1, rng, counters, max_steps):
    """render.transmittance = "auto" on a fixed ray, where the estimate's own variance is all
    the error (the transmittance benchmark, tests, a transmittance asked for on its own): the
    most efficient unbiased estimator there by the benchmark's measurements -- unbiased ray
    marching on every varying segment of a grey medium, telescoping in colour (exact on
    homogeneous ones). Single estimates can be negative. A render runs cheaper estimators,
    since its samples carry other noise (techniques.py: shadow rays of scattering paths
    ``transmittance_auto_shadow``, camera rays that cannot scatter residual ratio
    tracking)."""
    return transmittance_by_segments(med, o, d, t0, t1, auto_alone_kind(med), rng, counters,
                                     max_steps)


@njit(cache=True)
def transmittance_auto_shadow(med, o, d, t0, t1, rng, counters, max_steps):
    """render.transmittance = "auto" on the shadow rays of scattering paths: per segment,
    residual ratio tracking where it is optically thin, track length where it is thick
    (tracking.auto_segment_technique, where the rule and its measurements are)."""
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps, int(TRACK_AUTO))


@njit(cache=True)
def transmittance_biased_raymarch(med, o, d, t0, t1, rng, counters, max_steps):
    """Biased ray marching on every segment (``biased_raymarch_segment``). Biased."""
    return transmittance_by_segments(med, o, d, t0, t1, int(SEGMENT_BIASED_RAYMARCH), rng,
                                     counters, max_steps)


@njit(cache=True)
def transmittance_power_series(med, o, d, t0, t1, rng, counters, max_steps):
    """The p-series CMF power series (Georgiev et al. 2019) on every segment, with the
    segment's minorant as control (power_series.power_series_segment)."""
    return transmittance_by_segments(med, o, d, t0, t1, int(SEGMENT_POWER_SERIES), rng, counters,
                                     max_steps)


@njit(cache=True)
def transmittance_unbiased_raymarch(med, o, d, t0, t1, rng, counters, max_steps):
    """Unbiased ray marching (Kettunen et al. 2021) on every segment
    (power_series.unbiased_raymarch_segment). Single estimates can be negative."""
    return transmittance_by_segments(med, o, d, t0, t1, int(SEGMENT_UNBIASED_RAYMARCH), rng,
                                     counters, max_steps)


@njit(cache=True)
def transmittance_telescoping(med, o, d, t0, t1, rng, counters, max_steps):
    """The telescoping estimator over nested jittered ray marching (Misso et al. 2022) on
    every segment (debiasing.telescoping_segment). Unbiased; single estimates can be < 0."""
    return transmittance_by_segments(med, o, d, t0, t1, int(SEGMENT_TELESCOPING), rng, counters,
                                     max_steps)


@njit(cache=True)
def transmittance_jackknife(med, o, d, t0, t1, rng, counters, max_steps):
    """Jackknife-corrected ray marching on every segment (debiasing.jackknife_segment).
    Biased (second order in the step); single estimates can be < 0."""
    return transmittance_by_segments(med, o, d, t0, t1, int(SEGMENT_JACKKNIFE), rng, counters,
                                     max_steps)


@njit(cache=True)
def transmittance(est, med, o, d, t0, t1, rng, counters, max_steps):
    """Run the estimator with id ``est`` (ESTIMATOR_*; techniques.ESTIMATORS[name].id): the
    reference's run-time counterpart of the kernels' build-time choice. Returns RGB: the
    tracking estimators estimate every channel (colour-dependent extinction), the
    per-segment ones too, but the power series are grey (three equal channels)."""
    if est == ESTIMATOR_TRACK_LENGTH:
        return transmittance_track_length(med, o, d, t0, t1, rng, counters, max_steps)
    if est == ESTIMATOR_RATIO:
        return transmittance_ratio_tracking(med, o, d, t0, t1, rng, counters, max_steps)
    if est == ESTIMATOR_RESIDUAL_RATIO:
        return transmittance_residual_ratio(med, o, d, t0, t1, rng, counters, max_steps)
    if est == ESTIMATOR_NEXT_FLIGHT:
        return transmittance_next_flight(med, o, d, t0, t1, rng, counters, max_steps)
    if est == ESTIMATOR_BIASED_RAYMARCH:
        return transmittance_biased_raymarch(med, o, d, t0, t1, rng, counters, max_steps)
    if est == ESTIMATOR_POWER_SERIES:
        return transmittance_power_series(med, o, d, t0, t1, rng, counters, max_steps)
    if est == ESTIMATOR_UNBIASED_RAYMARCH:
        return transmittance_unbiased_raymarch(med, o, d, t0, t1, rng, counters, max_steps)
    if est == ESTIMATOR_TELESCOPING:
        return transmittance_telescoping(med, o, d, t0, t1, rng, counters, max_steps)
    if est == ESTIMATOR_JACKKNIFE:
        return transmittance_jackknife(med, o, d, t0, t1, rng, counters, max_steps)
    if est == ESTIMATOR_AUTO:
        return transmittance_auto(med, o, d, t0, t1, rng, counters, max_steps)
    if est == ESTIMATOR_AUTO_SHADOW:
        return transmittance_auto_shadow(med, o, d, t0, t1, rng, counters, max_steps)
    if est == ESTIMATOR_ANALYTIC:
        return transmittance_analytic(med, o, d, t0, t1, rng, counters, max_steps)
    raise ValueError("unknown estimator id")


@njit(cache=True, parallel=True)
def estimate_batch(est, media, grid, maj, mnr, nodes, rays, n_per_ray, seed, sample_offset,
                   max_steps):
    """n_per_ray estimates of estimator ``est`` for each ray (rows of ``rays``: o(3), d(3),
    t0, t1, pad), ray r through medium record media[r] (its majorant grid or octree -- maj,
    mnr, nodes -- and density grid shared).
    Estimate i uses ray i // n_per_ray and sample index sample_offset + i % n_per_ray on
    STREAM_TEST, like kernels/estimators.cl. Returns (estimates [n, 3], RGB, counters
    [n, N_COUNTERS])."""
    n = rays.shape[0] * n_per_ray
    out = np.empty((n, 3))
    counters = np.zeros((n, N_COUNTERS), np.int64)
    emis, table, bricks, pool, _, rec = no_field_arrays()
    for i in prange(n):
        r = i // n_per_ray
        rng = rng_new(seed, r, sample_offset + i % n_per_ray, STREAM_TEST)
        med = (MediumData(media[r], grid, maj, mnr, emis, table, bricks, pool, nodes, rec),)
        o = (rays[r, 0], rays[r, 1], rays[r, 2])
        d = (rays[r, 3], rays[r, 4], rays[r, 5])
        T = transmittance(est, med, o, d, rays[r, 6], rays[r, 7], rng, counters[i],
                          max_steps)
        out[i, 0], out[i, 1], out[i, 2] = T[0], T[1], T[2]
    return out, counters
