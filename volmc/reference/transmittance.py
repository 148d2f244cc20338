"""Tracking through the medium for free-flight sampling (the integrator's scattering events).

Transmittance estimators for shadow rays live in estimators.py.

All functions work on a ray o + t d restricted to [t0, t1] (world units along a unit d)
inside the medium box, with extinction mu(x) = scale * density(x) and a global majorant
``mbar`` >= mu. Every density lookup is counted in ``counters[C_LOOKUPS]``; lookups with
mu > mbar in ``counters[C_OVER_MAJORANT]``; walks that reach ``max_steps`` tentative
collisions are cut and counted in ``counters[C_CAPPED]`` (never silently).
Random numbers come from the caller's stream (``rng.py``), one per tentative collision
for the distance plus, for delta tracking, one per collision for the accept test.
"""

import math

import numpy as np
from numba import njit

from ..constants import EVENT_CAPPED, EVENT_ESCAPE, EVENT_SCATTER
from ..params import C_CAPPED, C_LOOKUPS, C_OVER_MAJORANT
from .dda import DDA_STATE_SIZE, dda_init, dda_next
from .grid import grid_lookup
from .rng import rng_next


@njit(cache=True, inline="always")
def sigma_t_at(grid, bmin, inv_extent, scale, o, d, t, counters, mbar):
    """Extinction (1/world unit) at o + t d, counting the lookup and majorant violations."""
    p = (o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2])
    mu = scale * grid_lookup(grid, bmin, inv_extent, p)
    counters[C_LOOKUPS] += 1
    if mu > mbar:
        counters[C_OVER_MAJORANT] += 1
    return mu


@njit(cache=True)
def free_flight_homogeneous(sigma_t, t0, t1, rng):
    """Analytic free flight in a homogeneous segment: t = t0 - ln(1 - u) / sigma_t.

    Returns (event, t): EVENT_SCATTER with t < t1, or EVENT_ESCAPE (t = t1).
    """
    if sigma_t <= 0.0:
        return EVENT_ESCAPE, t1
    t = t0 - math.log1p(-rng_next(rng)) / sigma_t
    if t >= t1:
        return EVENT_ESCAPE, t1
    return EVENT_SCATTER, t


@njit(cache=True)
def free_flight_delta(grid, bmin, inv_extent, scale, mbar, o, d, t0, t1, rng, counters, max_steps):
    """Delta (Woodcock) tracking: tentative collisions at rate mbar, each accepted as real
    with probability mu(x) / mbar. Unbiased for mbar >= mu. Returns (event, t).

    Guard "local distances" (HARD_CASES 11): the walk starts at o' = o + t0 d and accumulates
    the distance s from there, so t0 = 1e5 with mbar = 1e3 does not stall in float32
    (t + dt == t); the result is t0 + s."""
    if mbar <= 0.0:
        return EVENT_ESCAPE, t1
    inv_mbar = 1.0 / mbar
    o = (o[0] + t0 * d[0], o[1] + t0 * d[1], o[2] + t0 * d[2])
    L = t1 - t0
    s = 0.0
    for _ in range(max_steps):
        s -= math.log1p(-rng_next(rng)) * inv_mbar
        if s >= L:
            return EVENT_ESCAPE, t1
        mu = sigma_t_at(grid, bmin, inv_extent, scale, o, d, s, counters, mbar)
        if rng_next(rng) * mbar < mu:
            return EVENT_SCATTER, t0 + s
    counters[C_CAPPED] += 1
    return EVENT_CAPPED, t0 + s


@njit(cache=True)
def transmittance_homogeneous(sigma_t, t0, t1):
    """Exact transmittance exp(-sigma_t (t1 - t0)) of a homogeneous segment (0 lookups)."""
    return math.exp(-sigma_t * max(t1 - t0, 0.0))


@njit(cache=True)
def free_flight_grid(grid, bmin, bmax, inv_extent, scale, maj, mnr, use_control, o, d, t0, t1,
                     rng, counters, max_steps):
    """Free flight over a majorant grid: delta tracking (use_control False) or decomposition
    tracking (Kutz, Habel, Li, Novak 2017; use_control True). Returns (event, t).

    The segment is walked cell by cell with the 3-D DDA (dda.py); tentative collisions come at
    each cell's rate m = scale * maj[cell], and the exponential optical-depth budget left at a
    cell face carries into the next cell (the exponential is memoryless, so this equals
    re-sampling there); empty cells cost no lookup. One uniform u per tentative collision
    accepts it when u m < mu.

    Decomposition tracking splits mu = mu_c + mu_r with the cell minorant mu_c = scale *
    mnr[cell] as the control: control collisions (rate mu_c) need no lookup, residual ones
    (rate m - mu_c) are delta-tracked, and their superposition is a Poisson process of rate m
    in which a tentative collision is a control collision with probability mu_c / m. So
    u m < mu_c is a real collision decided without any lookup; otherwise the density is
    looked up as in delta tracking. For the same random numbers both variants make exactly
    the same decisions; decomposition tracking skips the lookups the control decides.
    ``maj``, ``mnr``: per-cell density maxima and minima [cz, cy, cx] (majorant.py).

    Guard "local distances" (HARD_CASES 11): the walk, the DDA included, runs from
    o' = o + t0 d over local distances [0, t1 - t0]; t0 is added back to the result."""
    o = (o[0] + t0 * d[0], o[1] + t0 * d[1], o[2] + t0 * d[2])
    state = np.empty(DDA_STATE_SIZE)
    dda_init(state, o, d, 0.0, t1 - t0, bmin, bmax, maj.shape)
    budget = -math.log1p(-rng_next(rng))
    steps = 0
    while True:
        ok, ta, tb, iz, iy, ix = dda_next(state)
        if not ok:
            return EVENT_ESCAPE, t1
        m = scale * maj[iz, iy, ix]
        if m <= 0.0:
            continue
        mc = scale * mnr[iz, iy, ix] if use_control else 0.0
        t = ta
        while True:
            step = budget / m
            if t + step >= tb:
                budget -= m * (tb - t)
                break
            t += step
            um = rng_next(rng) * m
            if um < mc:
                return EVENT_SCATTER, t0 + t
            if um < sigma_t_at(grid, bmin, inv_extent, scale, o, d, t, counters, m):
                return EVENT_SCATTER, t0 + t
            budget = -math.log1p(-rng_next(rng))
            steps += 1
            if steps >= max_steps:
                counters[C_CAPPED] += 1
                return EVENT_CAPPED, t0 + t
