"""Volumetric path tracer (Numba, float64): the reference every kernel is checked against.

One sample of pixel (x, y) (y = 0 is the top row) is one path:

1. Camera ray through the pixel, jittered uniformly inside it (two uniforms).
2. Free flight inside the medium box: analytic for a homogeneous medium, delta tracking
   for a grid, with the global majorant or (render.majorant = "grid") per-cell majorants
   along a 3-D DDA walk (empty cells cost nothing). Escaping the box ends the path and adds the
   environment radiance, weighted by MIS when the direction came from phase sampling.
3. At a real collision: the scattering event count rises; past ``max_depth`` the path
   ends. The throughput is multiplied by the albedo (sigma_s / sigma_t).
4. Next-event estimation to every light: directional and point lights are delta lights
   (one shadow ray each); the environment is sampled uniformly over the sphere and
   combined with phase sampling by the balance heuristic. Shadow-ray transmittance is
   analytic (homogeneous) or, in a grid, the estimator chosen by render.transmittance
   (ratio tracking by default; volmc/reference/estimators.py), on its own random stream.
   A medium that cannot scatter into the image (all albedos 0, or max_depth = 0) skips
   steps 2-6: the pixel is the environment times the transmittance along the camera ray.
5. Russian roulette from ``rr_depth`` scattering events on: the path survives with
   probability q = min(max_rgb(throughput), 0.95) and is divided by q (unbiased); the cap
   of 0.95 makes every path end even with albedo 1 in an infinitely dense medium.
6. A new direction is importance-sampled from the phase function; go to 2.

Random numbers: stream STREAM_PATH for all decisions of the path (in the order above),
stream STREAM_SHADOW for all shadow-ray transmittance estimates of the sample.
A sample whose contribution is NaN, infinite or negative is dropped (it counts as a sample
of value 0) and counted. Negative samples are legitimate only with a signed shadow estimator
(unbiased ray marching, params.signed_samples = 1): they are kept, since dropping them would
bias the pixel.
"""

import math

import numpy as np
from numba import njit, prange

from ..constants import (CAMERA_ORTHOGRAPHIC, EVENT_CAPPED, EVENT_ESCAPE, INV_4PI,
                         LIGHT_DIRECTIONAL, RR_MAX_SURVIVAL, STREAM_PATH, STREAM_SHADOW)
from ..params import C_DROPPED, C_SCATTER, C_SHADOW, N_COUNTERS
from .phase import phase_eval, phase_sample
from .rng import RNG_STATE_SIZE, rng_init, rng_next
from .sampling import dot, normalize, sample_uniform_sphere
from .estimators import estimate_one, transmittance_roulette
from .guards import sample_ok
from .dda import DDA_STATE_SIZE, dda_init, dda_next
from .transmittance import (free_flight_delta, free_flight_grid, free_flight_homogeneous,
                            transmittance_homogeneous)


@njit(cache=True, inline="always")
def ray_box(o, d, bmin, bmax):
    """Slab test of ray o + t d against the box. Returns (t_enter, t_exit); no hit when
    t_enter >= t_exit. Axis-parallel rays (d component 0 or -0) are handled without 0 * inf."""
    t0 = -math.inf
    t1 = math.inf
    for a in range(3):
        if d[a] == 0.0:
            if o[a] < bmin[a] or o[a] > bmax[a]:
                return math.inf, -math.inf
        else:
            inv = 1.0 / d[a]
            ta = (bmin[a] - o[a]) * inv
            tb = (bmax[a] - o[a]) * inv
            if ta > tb:
                ta, tb = tb, ta
            t0 = max(t0, ta)
            t1 = min(t1, tb)
    return t0, t1


@njit(cache=True, inline="always")
def enter_box(o, d, bmin, bmax):
    """Guard "entry re-basing" (HARD_CASES 10, 11, 13): clip ray o + t d to the box and, when
    the box is entered from outside (t_enter > 0), move the origin to the entry point, snapped
    onto the box (clamped into it, and exactly onto the entry face), and clip again from there.
    Every later distance is then local to the box: no tracking loop accumulates a large t (a
    far camera), the chord comes from nearby numbers (exact for a thin slab seen from afar),
    and a dense medium is entered exactly at its face, never a rounding error inside it (in
    a medium of extinction 1e30 that would bury the path: every direction blocked).

    Returns (origin, t0, t1, shift): the origin to use, the local segment (no medium when
    t1 <= t0) and the distance the origin moved along d."""
    te, t1 = ray_box(o, d, bmin, bmax)
    if not (te > 0.0 and t1 > te):
        return o, max(te, 0.0), t1, 0.0
    entry = 0
    best = -math.inf
    for a in range(3):
        if d[a] != 0.0:
            tin = ((bmin[a] if d[a] > 0.0 else bmax[a]) - o[a]) / d[a]
            if tin > best:
                best = tin
                entry = a
    p0 = min(max(o[0] + te * d[0], bmin[0]), bmax[0])
    p1 = min(max(o[1] + te * d[1], bmin[1]), bmax[1])
    p2 = min(max(o[2] + te * d[2], bmin[2]), bmax[2])
    face = bmin[entry] if d[entry] > 0.0 else bmax[entry]
    if entry == 0:
        p0 = face
    elif entry == 1:
        p1 = face
    else:
        p2 = face
    p = (p0, p1, p2)
    _, t1 = ray_box(p, d, bmin, bmax)
    return p, 0.0, t1, te


@njit(cache=True, inline="always")
def camera_ray(prm, px, py, u1, u2):
    """Primary ray through film position (px + u1, py + u2) (pixels; py = 0 at the top).

    Returns (origin, unit direction)."""
    sx = (2.0 * (px + u1) / prm.width - 1.0) * prm.half_height * prm.aspect
    sy = (1.0 - 2.0 * (py + u2) / prm.height) * prm.half_height
    f, r, u, e = prm.forward, prm.right, prm.up, prm.eye
    if prm.cam_type == CAMERA_ORTHOGRAPHIC:
        o = (e[0] + sx * r[0] + sy * u[0], e[1] + sx * r[1] + sy * u[1],
             e[2] + sx * r[2] + sy * u[2])
        return o, (f[0], f[1], f[2])
    d = normalize((f[0] + sx * r[0] + sy * u[0], f[1] + sx * r[1] + sy * u[1],
                   f[2] + sx * r[2] + sy * u[2]))
    return (e[0], e[1], e[2]), d


@njit(cache=True, inline="always")
def shadow_transmittance(prm, med, grid, maj_max, maj_min, o, d, t_max, rng_s, counters):
    """Transmittance from o towards unit d up to distance t_max (inf for distant lights):
    analytic in a homogeneous medium, else the estimator render.transmittance chose, with the
    global bounds or, over a majorant grid, per DDA segment with that cell's bounds (the
    product of independent unbiased per-segment estimates is unbiased; empty cells give 1
    with no lookup)."""
    bmin = (prm.bmin[0], prm.bmin[1], prm.bmin[2])
    bmax = (prm.bmax[0], prm.bmax[1], prm.bmax[2])
    o, t0, t1, shift = enter_box(o, d, bmin, bmax)
    t1 = min(t1, t_max - shift)
    if t1 <= t0:
        return 1.0
    counters[C_SHADOW] += 1
    if prm.has_grid == 0:
        return transmittance_homogeneous(prm.scale * prm.density, t0, t1)
    if prm.has_majorant_grid == 0:
        return estimate_one(prm.shadow_estimator, med, grid, o, d, t0, t1, prm.majorant,
                            prm.minorant, rng_s, counters, prm.max_steps, 1.0)
    state = np.empty(DDA_STATE_SIZE)
    dda_init(state, o, d, t0, t1, bmin, bmax, (prm.maj_res[0], prm.maj_res[1], prm.maj_res[2]))
    T = 1.0
    while True:
        ok, ta, tb, iz, iy, ix = dda_next(state)
        if not ok:
            break
        m = prm.scale * maj_max[iz, iy, ix]
        if m <= 0.0 or tb <= ta:
            continue
        T *= estimate_one(prm.shadow_estimator, med, grid, o, d, ta, tb, m,
                          prm.scale * maj_min[iz, iy, ix], rng_s, counters, prm.max_steps, 1.0)
        # Transmittance roulette over the product of segments (T == 0 ends it too).
        alive, T = transmittance_roulette(T, rng_s)
        if not alive:
            break
    return T


@njit(cache=True)
def trace_path(prm, lights, med, grid, maj_max, maj_min, px, py, rng, rng_s, counters):
    """Radiance (r, g, b) carried by one path through pixel (px, py)."""
    bmin = (prm.bmin[0], prm.bmin[1], prm.bmin[2])
    bmax = (prm.bmax[0], prm.bmax[1], prm.bmax[2])
    inv_ext = (prm.inv_extent[0], prm.inv_extent[1], prm.inv_extent[2])
    sigma_h = prm.scale * prm.density
    Lr = 0.0
    Lg = 0.0
    Lb = 0.0
    br = 1.0
    bg = 1.0
    bb = 1.0
    u1 = rng_next(rng)
    u2 = rng_next(rng)
    o, d = camera_ray(prm, px, py, u1, u2)
    if prm.max_depth == 0 or max(prm.albedo[0], max(prm.albedo[1], prm.albedo[2])) <= 0.0:
        # No scattering can contribute: the pixel is the environment seen through the
        # medium, so estimate the transmittance instead of sampling a collision (exact for
        # a homogeneous medium, lower variance than a 0/1 free-flight outcome for grids).
        if prm.has_env == 0:
            return 0.0, 0.0, 0.0
        tr = shadow_transmittance(prm, med, grid, maj_max, maj_min, o, d, math.inf, rng_s,
                                  counters)
        return tr * prm.env[0], tr * prm.env[1], tr * prm.env[2]
    depth = 0
    pdf_phase = 0.0  # pdf of the direction d when it came from phase sampling
    while True:
        o, t0, t1, _ = enter_box(o, d, bmin, bmax)
        event = EVENT_ESCAPE
        t = t1
        if t1 > t0:
            if prm.has_grid == 0:
                event, t = free_flight_homogeneous(sigma_h, t0, t1, rng)
            elif prm.has_majorant_grid != 0:
                event, t = free_flight_grid(grid, bmin, bmax, inv_ext, prm.scale, maj_max,
                                            maj_min, prm.decomposition != 0, o, d, t0, t1, rng,
                                            counters, prm.max_steps)
            else:
                event, t = free_flight_delta(grid, bmin, inv_ext, prm.scale, prm.majorant, o, d,
                                             t0, t1, rng, counters, prm.max_steps)
        if event == EVENT_CAPPED:
            break
        if event == EVENT_ESCAPE:
            if prm.has_env != 0:
                w = 1.0
                if depth > 0:
                    w = pdf_phase / (pdf_phase + INV_4PI)
                Lr += br * prm.env[0] * w
                Lg += bg * prm.env[1] * w
                Lb += bb * prm.env[2] * w
            break
        depth += 1
        if prm.max_depth >= 0 and depth > prm.max_depth:
            break
        counters[C_SCATTER] += 1
        br *= prm.albedo[0]
        bg *= prm.albedo[1]
        bb *= prm.albedo[2]
        if max(br, max(bg, bb)) <= 0.0:
            break
        p = (o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2])
        # Next-event estimation: delta lights.
        for i in range(prm.n_lights):
            lt = lights[i]
            if lt.type == LIGHT_DIRECTIONAL:
                wl = (-lt.vec[0], -lt.vec[1], -lt.vec[2])
                dist = math.inf
                falloff = 1.0
            else:
                v = (lt.vec[0] - p[0], lt.vec[1] - p[1], lt.vec[2] - p[2])
                dist2 = dot(v, v)
                if dist2 <= 0.0:
                    continue
                dist = math.sqrt(dist2)
                wl = (v[0] / dist, v[1] / dist, v[2] / dist)
                falloff = 1.0 / dist2
            f = phase_eval(prm.phase_kind, prm.g, dot(d, wl)) * falloff
            tr = shadow_transmittance(prm, med, grid, maj_max, maj_min, p, wl, dist, rng_s,
                                      counters)
            Lr += br * f * tr * lt.color[0]
            Lg += bg * f * tr * lt.color[1]
            Lb += bb * f * tr * lt.color[2]
        # Next-event estimation: environment, uniform sphere sampling + balance heuristic.
        if prm.has_env != 0:
            wl, pdf_l = sample_uniform_sphere(rng_next(rng), rng_next(rng))
            f = phase_eval(prm.phase_kind, prm.g, dot(d, wl))
            tr = shadow_transmittance(prm, med, grid, maj_max, maj_min, p, wl, math.inf, rng_s,
                                      counters)
            c = f * tr / (pdf_l + f)
            Lr += br * c * prm.env[0]
            Lg += bg * c * prm.env[1]
            Lb += bb * c * prm.env[2]
        # Russian roulette.
        if depth >= prm.rr_depth:
            q = min(max(br, max(bg, bb)), RR_MAX_SURVIVAL)
            if rng_next(rng) >= q:
                break
            br /= q
            bg /= q
            bb /= q
        u1 = rng_next(rng)
        u2 = rng_next(rng)
        d, pdf_phase = phase_sample(prm.phase_kind, prm.g, u1, u2, d)
        o = p
    return Lr, Lg, Lb


@njit(cache=True)
def render_pixel(params, lights, med, grid, maj_max, maj_min, pix, sample_start, n_samples,
                 film_sum, film_sq, counters):
    """Add samples [sample_start, sample_start + n_samples) of pixel ``pix`` to the film."""
    prm = params[0]
    py = pix // prm.width
    px = pix - py * prm.width
    seed = (np.uint64(prm.seed_hi) << np.uint64(32)) | np.uint64(prm.seed_lo)
    rng = np.empty(RNG_STATE_SIZE, np.uint32)
    rng_s = np.empty(RNG_STATE_SIZE, np.uint32)
    cnt = counters[pix]
    sr = 0.0
    sg = 0.0
    sb = 0.0
    qr = 0.0
    qg = 0.0
    qb = 0.0
    for s in range(sample_start, sample_start + n_samples):
        rng_init(rng, seed, pix, s, STREAM_PATH)
        rng_init(rng_s, seed, pix, s, STREAM_SHADOW)
        r, g, b = trace_path(prm, lights, med, grid, maj_max, maj_min, px, py, rng, rng_s, cnt)
        if not sample_ok(r, g, b, prm.signed_samples):
            cnt[C_DROPPED] += 1  # the sample counts as 0 (guard "sample filter", guards.py)
            continue
        sr += r
        sg += g
        sb += b
        qr += r * r
        qg += g * g
        qb += b * b
    film_sum[py, px, 0] += sr
    film_sum[py, px, 1] += sg
    film_sum[py, px, 2] += sb
    film_sq[py, px, 0] += qr
    film_sq[py, px, 1] += qg
    film_sq[py, px, 2] += qb


@njit(cache=True, parallel=True)
def render_batch(params, lights, med, grid, maj_max, maj_min, sample_start, n_samples, film_sum,
                 film_sq, counters):
    """Add samples [sample_start, sample_start + n_samples) of every pixel to the film.

    params: one-element array of ``params_dtype(float64)``; lights: array of
    ``light_dtype(float64)``; med: the grid's extinction source for the shadow-ray
    estimators (``pack.medium_array``); grid: float64 [nz, ny, nx] (ignored unless has_grid);
    maj_max, maj_min: per-cell density bounds [cz, cy, cx] (used when has_majorant_grid);
    film_sum, film_sq: float64 [height, width, 3] running sums of sample values and of their
    squares; counters: int64 [height * width, N_COUNTERS], accumulated in place.
    Pixels are independent, so the loop over them runs in parallel.
    """
    n_pix = film_sum.shape[0] * film_sum.shape[1]
    for pix in prange(n_pix):
        render_pixel(params, lights, med, grid, maj_max, maj_min, pix, sample_start, n_samples,
                     film_sum, film_sq, counters)


def new_counters(width, height):
    """Zeroed per-pixel counter array for ``render_batch``."""
    return np.zeros((width * height, N_COUNTERS), np.int64)
