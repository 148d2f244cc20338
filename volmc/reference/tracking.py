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

Returns (event, t, T): the free-flight outcome and distance (t1 on escape; the ray parameter
of the original o), and the transmittance estimate of the transmittance techniques.
"""

import math

import numpy as np
from numba import njit, prange

from ..constants import (EVENT_CAPPED, EVENT_ESCAPE, EVENT_SCATTER, STREAM_TEST, TR_RR_THRESHOLD,
                         TRACK_FREE_FLIGHT, TRACK_LENGTH, TRACK_NEXT_FLIGHT,
                         TRACK_RESIDUAL_RATIO)
from ..params import C_CAPPED, C_LOOKUPS, N_COUNTERS
from .medium import (ITER_STATE_SIZE, MediumData, extinction, majorant_iter_init,
                     majorant_next)
from .rng import rng_new, rng_next
from .sampling import sample_exponential
from .vec import madd3


@njit(cache=True, inline="always")
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
def track(med, o, d, t0, t1, technique, use_control, rng, counters, max_steps):
    """Walk ray o + t d over [t0, t1] through ``med`` with ``technique`` (TRACK_*).
    Returns (event, t, T) (module docstring)."""
    o = madd3(o, d, t0)
    it = np.empty(ITER_STATE_SIZE)
    majorant_iter_init(it, med, o, d, 0.0, t1 - t0)
    flight = technique == TRACK_FREE_FLIGHT or technique == TRACK_LENGTH
    budget = -1.0   # optical depth left to the next tentative collision; < 0: not drawn yet
    T = 1.0
    steps = 0
    while True:
        ok, ta, tb, s_maj, s_min = majorant_next(it, med)
        if not ok:
            return EVENT_ESCAPE, t1, T
        homogeneous = s_min == s_maj
        # Roulette on the product so far before spending work on another segment (a no-op
        # while T >= TR_RR_THRESHOLD, so on the first segment). Track length keeps its
        # estimate 0 or 1: a fraction left by homogeneous segments goes on with probability T
        # as 1, so a shadow ray stops in a dense homogeneous core as soon as delta tracking
        # would, while a homogeneous medium (one segment) stays exact.
        if technique == TRACK_LENGTH and T < 1.0:
            if rng_next(rng) >= T:
                return EVENT_ESCAPE, t1, 0.0
            T = 1.0
        if technique != TRACK_FREE_FLIGHT:
            alive, T = transmittance_roulette(T, rng)
            if not alive:
                return EVENT_ESCAPE, t1, T
        if homogeneous and technique != TRACK_FREE_FLIGHT:
            T *= math.exp(-s_maj * (tb - ta))
            continue
        control = 0.0
        if homogeneous or technique == TRACK_RESIDUAL_RATIO or (flight and use_control):
            control = s_min
        rate = s_maj - control if technique == TRACK_RESIDUAL_RATIO else s_maj
        inv_rate = 1.0 / rate   # a multiplication per step instead of a division
        if technique == TRACK_RESIDUAL_RATIO:
            T *= math.exp(-control * (tb - ta))
        w = 1.0                                  # next flight: weight of the current vertex
        # next flight: this segment's estimate (no exp for the other techniques)
        acc = math.exp(-s_maj * (tb - ta)) if technique == TRACK_NEXT_FLIGHT else 0.0
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
            if flight:
                # Real for sure where the control covers the majorant (no draw, no lookup).
                real = control >= s_maj
                if not real:
                    um = rng_next(rng) * s_maj
                    real = um < control or um < extinction(med, p, s_maj, counters)
                if real:
                    return EVENT_SCATTER, t0 + t, 0.0
            elif technique == TRACK_NEXT_FLIGHT:
                w *= 1.0 - extinction(med, p, s_maj, counters) / s_maj
                alive, w = transmittance_roulette(w, rng)
                if not alive:
                    budget = -1.0   # the next segment draws afresh
                    break   # the rest of this segment adds nothing; its estimate is acc
                acc += w * math.exp(-s_maj * (tb - t))
            else:
                T *= 1.0 - (extinction(med, p, s_maj, counters) - control) / rate
                alive, T = transmittance_roulette(T, rng)
                if not alive:
                    return EVENT_ESCAPE, t1, T
            budget = sample_exponential(rng_next(rng), 1.0)[0]
            steps += 1
            if steps >= max_steps:
                counters[C_CAPPED] += 1
                if technique == TRACK_NEXT_FLIGHT:
                    T *= acc
                return EVENT_CAPPED, t0 + t, 0.0 if flight else T
        if technique == TRACK_NEXT_FLIGHT:
            T *= acc


@njit(cache=True, parallel=True)
def track_batch(technique, use_control, media, grid, maj, mnr, rays, n_per_ray, seed,
                max_steps):
    """``track`` over batches of rays, for tests and benchmarks (twin of the t_track test
    kernel): walk i follows ray r = i // n_per_ray (rows o(3), d(3), t0, t1, pad) through
    media[r] with sample index i % n_per_ray on STREAM_TEST. Returns (t [n]: the collision
    distance, -1 on escape, -2 if capped; T [n]: the transmittance estimate; lookups [n])."""
    n = rays.shape[0] * n_per_ray
    t_out = np.empty(n)
    T_out = np.empty(n)
    lookups = np.empty(n, np.int64)
    for i in prange(n):
        r = i // n_per_ray
        rng = rng_new(seed, r, i % n_per_ray, STREAM_TEST)
        counters = np.zeros(N_COUNTERS, np.int64)
        med = MediumData(media[r], grid, maj, mnr)
        ev, t, T = track(med, (rays[r, 0], rays[r, 1], rays[r, 2]),
                         (rays[r, 3], rays[r, 4], rays[r, 5]), rays[r, 6], rays[r, 7],
                         technique, use_control, rng, counters, max_steps)
        t_out[i] = t if ev == EVENT_SCATTER else (-2.0 if ev == EVENT_CAPPED else -1.0)
        T_out[i] = T
        lookups[i] = counters[C_LOOKUPS]
    return t_out, T_out, lookups
