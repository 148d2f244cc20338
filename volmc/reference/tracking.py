"""The tracking loop, written once: tentative collisions along a ray over the medium's
majorant segments, and what each technique does at them. Twin of ``kernels/tracking.h``.

``track`` walks the ray o + t d over [t0, t1] (inside the medium box). On each majorant
segment (medium.py) tentative collisions form a Poisson process of rate
``sigma_maj - control`` (the control is 0 except for residual ratio tracking); distances come
from one exponential "optical-depth budget" (``sample_exponential`` with rate 1) that is
spent at the segment's rate and carried into the next segment when a segment ends first. The
exponential is memoryless, so carrying the rest of the budget equals drawing afresh at each
segment, and it costs no random number at a cell face. A new budget is drawn after every
tentative collision that does not end the walk; the first is drawn only when a segment
needs one, so a transmittance walk through empty and homogeneous segments draws nothing (but
track length's roulette, below).

What happens at a tentative collision at distance t, by ``technique``:

* ``TRACK_FREE_FLIGHT`` (delta tracking, or decomposition tracking (Kutz et al. 2017) with
  ``use_control``): one uniform u; the collision is real if u sigma_maj < mu_c (the
  segment's minorant, when used as control: no lookup) or u sigma_maj < mu(t). A real
  collision ends the walk: EVENT_SCATTER at t. For the same random numbers delta and
  decomposition tracking make the same decisions; decomposition skips the lookups the
  control decides.
* ``TRACK_LENGTH``: the same walk as free flight, read as a transmittance estimate: T = 1 if
  it escapes past t1, 0 at a real collision.
* ``TRACK_RATIO`` (Cramer 1978; Novak, Selle, Jarosz 2014): T *= 1 - mu(t) / sigma_maj.
* ``TRACK_RESIDUAL_RATIO`` (Novak et al. 2014): the segment's minorant mu_c is the control:
  T *= exp(-mu_c L) once per segment of length L, and collisions come at the residual rate
  sigma_maj - mu_c with T *= 1 - (mu(t) - mu_c) / (sigma_maj - mu_c).
* ``TRACK_AUTO`` (render.transmittance = "auto" on shadow rays): per segment, the technique
  ``auto_segment_technique`` picks from the segment's bounds and length -- residual ratio
  tracking or track length, each as above; a real collision on a track-length segment ends
  the walk with T = 0, a fraction left by residual segments carries on otherwise.
* ``TRACK_NEXT_FLIGHT`` (next-flight ratio tracking; Novak et al. 2018's survey, Georgiev
  et al. 2019): per segment, each vertex of a ratio-tracking walk (the segment start with
  weight 1, then every tentative collision) adds its weight times the probability
  exp(-sigma_maj (t_max - t)) that the next flight leaves the segment; the segments'
  estimates multiply.

A product of independent unbiased per-segment estimates is unbiased, and the tentative
collisions of disjoint segments are independent, so every technique is unbiased over any
majorant structure.

Homogeneous segments (sigma_min == sigma_maj: the density is constant there) are exact: a
transmittance technique multiplies T by exp(-sigma_maj L) with no lookup and no random
number, and free flight accepts its first tentative collision there without a lookup or an
accept draw (it is real with probability 1; its distance still takes the budget). So a
homogeneous medium is tracked analytically.

Between segments the running estimate plays transmittance roulette (below): with exact
homogeneous segments even track length's estimate can become a small fraction, and a dense
homogeneous core must not send a shadow ray on through the rest of the medium.

Guards (docs/robustness.md): "local distances" -- the walk starts at o' = o + t0 d and
accumulates distances from 0, so a segment far along its ray (t0 = 1e5 with a majorant of
1e3, where t + dt == t in float32) cannot stall; "step cap" -- a walk that reaches
``max_steps`` tentative collisions ends, is counted in counters[C_CAPPED], and returns
EVENT_CAPPED (free flight) or T as it stands (track length: 0); "transmittance roulette" --
ratio-type weights below TR_RR_THRESHOLD play Russian roulette (``transmittance_roulette``),
so dense shadow rays stop after a few lookups.

Colour (``m.spectral``; docs/colour_emission.md, "Colour-dependent extinction"): extinction per channel is
chroma_c x mu(x), with mu the largest channel's extinction (what ``extinction`` returns and
every majorant bounds) and chroma_c <= 1. So one majorant serves all three channels, the
segments and the tentative collisions are shared, and

* the ratio-type techniques multiply each channel by its own factor (1 - chroma_c mu /
  sigma_maj, exp(-chroma_c sigma L) on homogeneous segments): RGB transmittance from the
  same lookups;
* free flight and track length use spectral tracking (Kutz et al. 2017, ``spectral_choice``):
  a tentative collision is real with a probability from the channels' weighted collision
  and null coefficients, and each channel's weight is corrected by its own coefficient over
  that probability; ``beta`` (the path throughput) makes the choice history-aware. A grey
  medium (SPECTRAL_GREY) takes delta tracking's decisions and weights 1.
* hero-channel spectral MIS (SPECTRAL_HERO, ``hero`` >= 0; Miller et al. 2019) is the same
  choice with the hero's one-hot weights: the hero's delta tracking decides, and the
  factors are each channel's probability of the decision over the hero's. The integrator
  accumulates them (``beta`` then carries those ratios R) and weighs channel c by the
  balance heuristic R_c / mean(R) (``mis_weights``), as emission here is weighed.

Emission (``m.emission_kind``): free flight adds W sigma_a(x) Le(x) / sigma_maj at every
tentative collision (``emission_term``; the collision estimator of pbrt-v4 and Cycles),
homogeneous segments and those the control decides included.

Returns (event, t, T, E): the free-flight outcome and distance (t1 on escape; the ray
parameter of the original o); T (RGB): the transmittance estimate of the transmittance
techniques, or free flight's spectral-tracking weight ((1, 1, 1) for a grey medium); E (RGB):
the emission free flight gathered, per unit beta. The kernels carry T as ``spec``
(kernels/spectrum.h): float in builds without colour, where the three channels are equal.
"""

import math

import numpy as np
from numba import njit, prange

from ..constants import (AUTO_THIN_DEPTH, EMISSION_NONE, EVENT_CAPPED, EVENT_ESCAPE,
                         EVENT_SCATTER, SPECTRAL_GREY, STREAM_TEST, TR_RR_THRESHOLD, TRACK_AUTO,
                         TRACK_FREE_FLIGHT, TRACK_LENGTH, TRACK_NEXT_FLIGHT,
                         TRACK_RESIDUAL_RATIO)
from ..params import C_CAPPED, C_LOOKUPS, N_COUNTERS
from .medium import (MediumData, emitted_radiance, extinction_in, has_medium,
                     majorant_iter_init, majorant_next, media_emit, medium_chroma,
                     medium_extinction, new_iter, no_field_arrays)
from .rng import rng_new, rng_next
from .emitters import emitter_pdf
from .sampling import mis_weight, sample_exponential
from .vec import add3, exp_neg3, madd3, max3, mul3, mul_one_minus3, scale3

ZERO3 = (0.0, 0.0, 0.0)
ONE3 = (1.0, 1.0, 1.0)


@njit(cache=True)
def transmittance_roulette(T, rng):
    """Russian roulette on a running transmittance weight. Returns (alive, T).

    Once |T| < TR_RR_THRESHOLD the walk survives with probability q = |T| / TR_RR_THRESHOLD
    and carries T / q = +-TR_RR_THRESHOLD, else it ends with T = 0: E[T] is unchanged
    (unbiased), and T == 0 ends the walk at once. Dense media (robustness case 10: majorant
    optical depth 1e6) then cost a few lookups per shadow ray instead of the whole walk. The
    added variance is at most TR_RR_THRESHOLD^2 per estimate."""
    a = abs(T)
    if not a < TR_RR_THRESHOLD:
        return True, T
    if a == 0.0 or rng_next(rng) * TR_RR_THRESHOLD >= a:
        return False, 0.0
    return True, TR_RR_THRESHOLD if T > 0.0 else -TR_RR_THRESHOLD


@njit(cache=True)
def spec_roulette(T, rng):
    """``transmittance_roulette`` on an RGB weight, by its largest |component| a: below the
    threshold the walk survives with probability a / TR_RR_THRESHOLD and every component is
    divided by it (each channel's expectation unchanged). A grey weight gives the grey
    roulette's decisions."""
    a = max3((abs(T[0]), abs(T[1]), abs(T[2])))
    if not a < TR_RR_THRESHOLD:
        return True, T
    if a == 0.0 or rng_next(rng) * TR_RR_THRESHOLD >= a:
        return False, ZERO3
    return True, scale3(T, TR_RR_THRESHOLD / a)


@njit(cache=True)
def emission_term(med, media, p, mu, s_maj, W, counters):
    """What one tentative collision at p adds to the emission estimate: W sigma_a(p) Le(p) /
    sigma_maj per channel, sigma_a = (1 - albedo) x chroma x mu the absorption coefficient,
    W the weight so far. Summed over every tentative collision of a walk at rate sigma_maj
    it estimates the integral of T sigma_a Le along the ray without bias (the collision
    estimator of pbrt-v4 and Cycles). Several media: the sum of every emitting medium's
    sigma_a Le, each from its own counted lookup (mu, the sum, does not split), over the
    media in ``media`` (a bit each: the segment's, ``majorant_next``)."""
    k = medium_chroma(med)
    out = ZERO3
    for i in range(len(med)):
        m = med[i].m
        if m.emission_kind == EMISSION_NONE or not has_medium(media, i):
            continue
        s = (mu if len(med) == 1 else medium_extinction(med, i, p, counters)) / s_maj
        Le = emitted_radiance(med, i, p)
        out = add3(out, ((1.0 - m.albedo[0]) * k[0] * s * Le[0] * W[0],
                         (1.0 - m.albedo[1]) * k[1] * s * Le[1] * W[1],
                         (1.0 - m.albedo[2]) * k[2] * s * Le[2] * W[2]))
    return out


#: ``track``'s ``emis`` for a walk whose emission is not weighed against emission sampling.
EMIS_PLAIN = (-1.0, 0.0, 0.0, 0.0)


@njit(cache=True)
def emission_weight(emis, med, p, s_maj, dist):
    """MIS weight of the emission a free flight gathers at a tentative collision p against
    emission sampling (render.emission_sampling; integrator.py ``sample_emitters``).
    emis = (pdf_dir, shift, n, heuristic): pdf_dir < 0 for 1 (the collision estimator
    alone: a camera ray, or render.emission_sampling = "collision"), else the density per
    steradian the flight's direction was sampled with (0 with "light": the weight is then 0
    wherever emission sampling reaches); shift how far the walk's origin lies from the
    vertex; n the emitter samples per vertex; heuristic render.mis. dist: p's distance from
    the vertex, s_maj the majorant there.

    The heuristic compares pdf_dir sigma_maj(p) / dist^2 with n times emission sampling's
    density at p (docs/emission_sampling.md): in the null-scattering path space (Miller et
    al. 2019) a tentative collision at p has the density pdf_dir sigma_maj(p) T_maj / dist^2
    times the probabilities of the null events before it, and emission sampling with a
    delta-tracking shadow ray (track length) reaches the same path with density pdf(p) T_maj
    times the same null probabilities: they cancel, so the weight depends on p alone, and
    both strategies compute it without the transmittance. Any weight that is a function of
    the vertex and p and sums to 1 over the strategies keeps the sum unbiased, whatever
    estimator the shadow rays use. Where emission sampling has no density the weight is 1."""
    if emis[0] < 0.0:
        return 1.0
    pl = emis[2] * emitter_pdf(med, p)
    if not pl > 0.0:
        return 1.0
    # Both densities times dist^2: pdf_dir s_maj / dist^2 overflowed float32 at a tentative
    # collision 1e-15 from the vertex in a dense emitter (inf / inf, a NaN sample).
    if emis[0] == 0.0:   # "light" (its weight 0 even where pl dist^2 underflows to 0)
        return 0.0
    return mis_weight(int(emis[3]), emis[0] * s_maj, pl * dist * dist)


@njit(cache=True)
def spectral_choice(W, k, mu, s_maj, u):
    """Spectral tracking's choice at a tentative collision (Kutz et al. 2017, the
    history-aware maximum rule): with weights W (RGB), per-channel extinction k mu and null
    coefficient s_maj - k mu, the collision is real with probability
    P = A / (A + B), A = max_c W_c k_c mu, B = max_c W_c (s_maj - k_c mu), decided by u < P.
    Returns (real, factor): the weight factor k mu / (s_maj P) (real) or
    (s_maj - k mu) / (s_maj (1 - P)) (null), RGB; every channel's expectation is then its
    own collision or null coefficient / s_maj, so each channel is unbiased, and a grey
    medium with equal weights reduces to delta tracking with factors 1. (False, 0) when
    every weight is 0."""
    a = max3((W[0] * k[0] * mu, W[1] * k[1] * mu, W[2] * k[2] * mu))
    n = (s_maj - k[0] * mu, s_maj - k[1] * mu, s_maj - k[2] * mu)
    b = max3(mul3(W, n))
    if not a + b > 0.0:
        return False, ZERO3
    if u * (a + b) < a:
        return True, scale3(k, mu * (a + b) / (s_maj * a))
    return False, scale3(n, (a + b) / (s_maj * b))


@njit(cache=True)
def mis_weights(R):
    """Hero MIS: R (RGB) holds each channel's probability of the path's decisions relative
    to any common factor; the balance heuristic over the three channels as hero (each chosen
    with probability 1/3) weighs channel c by R_c / mean(R). 0 when every R is 0."""
    s = (R[0] + R[1] + R[2]) / 3.0
    if not s > 0.0:
        return ZERO3
    return (R[0] / s, R[1] / s, R[2] / s)


@njit(cache=True)
def auto_segment_technique(s_maj, s_min, L):
    """The technique ``TRACK_AUTO`` uses on one majorant segment of extinction bounds
    [s_min, s_maj] (1/unit) and length L (units): residual ratio tracking if the segment's
    majorant-minorant gap (s_maj - s_min) L is at most AUTO_THIN_DEPTH mean free paths, track
    length otherwise. Both are unbiased per segment, and the choice depends only on the
    segment's bounds, never on its random numbers, so the product stays unbiased.

    Why (docs/which_estimator.md, measured with ``volmc bench render`` on the default
    cloud, the plume, the scan and the thin cloud): a shadow ray's variance is a small part of
    a scattering path's, so cost decides. On a thick segment track length stops at the first
    real collision, where ratio-type tracking goes on until roulette (the cloud: 13.2 against
    23.2 lookups per sample, 1.28x the time to equal error). On a thin segment both make the
    same expected (s_maj - s_min) L lookups, and residual ratio tracking's weight is not 0 or
    1. Thresholds from 0.1 to 3 were measured: 0.1 was within noise of the best fixed
    estimator on every scene, 0.3 already cost the cloud 1.12x and 3 cost 1.43x."""
    return TRACK_RESIDUAL_RATIO if (s_maj - s_min) * L <= AUTO_THIN_DEPTH else TRACK_LENGTH


@njit(cache=True)
def track(med, o, d, t0, t1, technique, use_control, beta, hero, emis, rng, counters,
          max_steps):
    """Walk ray o + t d over [t0, t1] through ``med`` with ``technique`` (TRACK_*).
    Returns (event, t, T, E) (module docstring). Spectral free flight: with ``hero`` < 0,
    ``beta`` (RGB) is the path throughput the choices are weighed by (spectral tracking);
    with ``hero`` = c, channel c's delta tracking decides and ``beta`` holds the path's
    decision-probability ratios so far (hero MIS, below). ``emis``: how free flight weighs
    its emission against emission sampling (``emission_weight``; EMIS_PLAIN: not)."""
    spectral = med[0].m.spectral != SPECTRAL_GREY
    emissive = technique == TRACK_FREE_FLIGHT and media_emit(med)
    weigh = emissive and emis[0] >= 0.0
    k = medium_chroma(med)
    o = madd3(o, d, t0)
    it = new_iter(med)
    majorant_iter_init(it, med, o, d, 0.0, t1 - t0)
    budget = -1.0   # optical depth left to the next tentative collision; < 0: not drawn yet
    T = ONE3
    E = ZERO3
    steps = 0
    while True:
        ok, ta, tb, s_maj, s_min, media = majorant_next(it, med)
        if not ok:
            return EVENT_ESCAPE, t1, T, E
        homogeneous = s_min == s_maj
        # This segment's technique: the walk's own, or auto's choice for it.
        tech = auto_segment_technique(s_maj, s_min, tb - ta) if technique == TRACK_AUTO \
            else technique
        flight = tech == TRACK_FREE_FLIGHT or tech == TRACK_LENGTH
        # Roulette on the product so far before spending work on another segment (a no-op
        # while T >= TR_RR_THRESHOLD, so on the first segment). Grey track length keeps its
        # estimate 0 or 1: a fraction left by homogeneous segments goes on with probability T
        # as 1, so a shadow ray stops in a dense homogeneous core as soon as delta tracking
        # would, while a homogeneous medium (one segment) stays exact.
        if technique == TRACK_LENGTH and not spectral and T[0] < 1.0:
            if rng_next(rng) >= T[0]:
                return EVENT_ESCAPE, t1, ZERO3, E
            T = ONE3
        if technique != TRACK_FREE_FLIGHT:
            alive, T = spec_roulette(T, rng)
            if not alive:
                return EVENT_ESCAPE, t1, T, E
        if homogeneous and technique != TRACK_FREE_FLIGHT:
            T = mul3(T, exp_neg3(k, s_maj * (tb - ta)))
            continue
        control = 0.0
        if homogeneous or tech == TRACK_RESIDUAL_RATIO or (flight and use_control):
            control = s_min
        rate = s_maj - control if tech == TRACK_RESIDUAL_RATIO else s_maj
        inv_rate = 1.0 / rate   # a multiplication per step instead of a division
        if tech == TRACK_RESIDUAL_RATIO:
            T = mul3(T, exp_neg3(k, control * (tb - ta)))
        w = ONE3                                 # next flight: weight of the current vertex
        # next flight: this segment's estimate (no exp for the other techniques)
        e_seg = math.exp(-s_maj * (tb - ta)) if technique == TRACK_NEXT_FLIGHT else 0.0
        acc = (e_seg, e_seg, e_seg)
        t = ta
        if budget < 0.0:
            budget = sample_exponential(rng_next(rng), 1.0)[0]
        while True:
            step = budget * inv_rate
            if t + step >= tb:
                # >= 0: rounding must not turn what is left into the "not drawn" marker
                budget = max(budget - rate * (tb - t), 0.0)
                break
            t += step
            p = madd3(o, d, t)
            if flight and spectral:
                # Spectral tracking: the density of a homogeneous segment needs no lookup.
                mu = s_maj if homogeneous else extinction_in(med, media, p, s_maj, counters)
                if hero >= 0:
                    # The hero's one-hot weights make spectral_choice the hero's delta
                    # tracking, its factors each channel's probability over the hero's.
                    W = (1.0 if hero == 0 else 0.0, 1.0 if hero == 1 else 0.0,
                         1.0 if hero == 2 else 0.0)
                    if emissive:
                        E = add3(E, emission_term(med, media, p, mu, s_maj, scale3(
                            mis_weights(mul3(T, beta)), weight_at(weigh, emis, med, p, s_maj, t0 + t)),
                            counters))
                else:
                    W = mul3(T, beta) if technique == TRACK_FREE_FLIGHT else T
                    if emissive:
                        E = add3(E, emission_term(med, media, p, mu, s_maj, scale3(
                            T, weight_at(weigh, emis, med, p, s_maj, t0 + t)), counters))
                real, f = spectral_choice(W, k, mu, s_maj, rng_next(rng))
                if real:
                    if tech == TRACK_LENGTH:
                        return EVENT_SCATTER, t0 + t, ZERO3, E
                    return EVENT_SCATTER, t0 + t, mul3(T, f), E
                T = mul3(T, f)
                if max3(T) <= 0.0:
                    return EVENT_ESCAPE, t1, ZERO3, E
                if hero >= 0:
                    # Only the ratios matter to hero MIS: keep them from overflowing.
                    T = scale3(T, 1.0 / max3(T))
            elif flight:
                # Real for sure where the control covers the majorant (no draw, no lookup).
                real = control >= s_maj
                mu = s_maj if real else -1.0   # -1: not looked up
                if not real:
                    um = rng_next(rng) * s_maj
                    real = um < control
                    if not real:
                        mu = extinction_in(med, media, p, s_maj, counters)
                        real = um < mu
                if emissive:
                    if mu < 0.0:
                        mu = extinction_in(med, media, p, s_maj, counters)
                    w_e = weight_at(weigh, emis, med, p, s_maj, t0 + t)
                    E = add3(E, emission_term(med, media, p, mu, s_maj, (w_e, w_e, w_e), counters))
                if real:
                    return EVENT_SCATTER, t0 + t, ONE3 if technique == TRACK_FREE_FLIGHT \
                        else ZERO3, E
            elif technique == TRACK_NEXT_FLIGHT:
                w = mul_one_minus3(w, k, extinction_in(med, media, p, s_maj, counters) / s_maj)
                alive, w = spec_roulette(w, rng)
                if not alive:
                    budget = -1.0   # the next segment draws afresh
                    break   # the rest of this segment adds nothing; its estimate is acc
                acc = add3(acc, scale3(w, math.exp(-s_maj * (tb - t))))
            else:
                T = mul_one_minus3(T, k, (extinction_in(med, media, p, s_maj, counters) - control)
                                   / rate)
                alive, T = spec_roulette(T, rng)
                if not alive:
                    return EVENT_ESCAPE, t1, T, E
            budget = sample_exponential(rng_next(rng), 1.0)[0]
            steps += 1
            if steps >= max_steps:
                counters[C_CAPPED] += 1
                if technique == TRACK_NEXT_FLIGHT:
                    T = mul3(T, acc)
                if technique == TRACK_LENGTH:
                    T = ZERO3
                return EVENT_CAPPED, t0 + t, T, E
        if technique == TRACK_NEXT_FLIGHT:
            T = mul3(T, acc)


@njit(cache=True)
def weight_at(weigh, emis, med, p, s_maj, t):
    """``emission_weight`` at distance t of a walk from o (1 when not weighing); the vertex
    lies emis[1] before o."""
    if not weigh:
        return 1.0
    return emission_weight(emis, med, p, s_maj, emis[1] + t)


@njit(cache=True, parallel=True)
def track_batch(technique, use_control, media, grid, maj, mnr, rays, n_per_ray, seed,
                max_steps):
    """``track`` over batches of rays, for tests and benchmarks (twin of the t_track test
    kernel): walk i follows ray r = i // n_per_ray (rows o(3), d(3), t0, t1, pad) through
    media[r] with sample index i % n_per_ray on STREAM_TEST and unit throughput. Returns
    (t [n]: the collision distance, -1 on escape, -2 if capped; T [n, 3]: the transmittance
    estimate or free flight's weight, RGB; lookups [n])."""
    n = rays.shape[0] * n_per_ray
    t_out = np.empty(n)
    T_out = np.empty((n, 3))
    lookups = np.empty(n, np.int64)
    emis, table, bricks, pool, nodes, rec = no_field_arrays()
    for i in prange(n):
        r = i // n_per_ray
        rng = rng_new(seed, r, i % n_per_ray, STREAM_TEST)
        counters = np.zeros(N_COUNTERS, np.int64)
        med = (MediumData(media[r], grid, maj, mnr, emis, table, bricks, pool, nodes, rec),)
        ev, t, T, _ = track(med, (rays[r, 0], rays[r, 1], rays[r, 2]),
                            (rays[r, 3], rays[r, 4], rays[r, 5]), rays[r, 6], rays[r, 7],
                            technique, use_control, ONE3, -1, EMIS_PLAIN, rng, counters,
                            max_steps)
        t_out[i] = t if ev == EVENT_SCATTER else (-2.0 if ev == EVENT_CAPPED else -1.0)
        T_out[i, 0] = T[0]
        T_out[i, 1] = T[1]
        T_out[i, 2] = T[2]
        lookups[i] = counters[C_LOOKUPS]
    return t_out, T_out, lookups
