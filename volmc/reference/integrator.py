"""Volumetric path tracer (Numba, float64): the reference every kernel is checked against.

Twin of ``kernels/integrator.cl``. One sample of pixel (x, y) (y = 0 is the top row) is one
path:

1. Camera ray through the pixel, jittered uniformly inside it (two uniforms), from a point
   of the lens when camera.aperture > 0 (two more; camera.py).
2. With render.equiangular, before the flight: every point and spot light's single
   scattering along the segment by equiangular sampling (``sample_equiangular_lights``).
   Free flight inside the medium box (free_flight.py): the one tracking loop over the
   medium's majorant segments -- analytic for a homogeneous medium, delta or decomposition
   tracking over the global majorant or the majorant grid (empty cells cost nothing).
   Escaping the box ends the path and adds the environment radiance, weighted by MIS when
   the direction came from phase sampling.
3. At a real collision: the scattering event count rises; past ``max_depth`` the path
   ends. The throughput is multiplied by the albedo (sigma_s / sigma_t).
4. Direct lighting (``sample_direct``): render.light_samples shadow rays to each
   parallel, point and spot light (a point or spot light's weighted against equiangular
   sampling when that is on), and as many directions sampled towards each sun disc and
   sphere light (lights.py) and the environment, combined with phase sampling by the
   balance or power heuristic (``mis_weight``, render.mis); a sphere light the flight's ray
   meets ends it, seen with the complementary weight. Shadow-ray transmittance is the
   estimator render.transmittance chose (estimators.py; exact on homogeneous segments), on
   its own random stream.
   With render.emission_sampling "light" or "mis": as many points drawn in the emitting
   media (``sample_emitters``; emitters.py), each a shadow ray; the flights after a
   scattering vertex weigh the emission they gather with the complement
   (tracking.emission_weight).
   A medium that cannot scatter into the image (all albedos 0, or max_depth = 0) skips
   steps 2-6: the pixel is the environment times the transmittance along the camera ray.
5. Russian roulette from ``rr_depth`` scattering events on: the path survives with
   probability q = min(max_rgb(throughput), cap) (render.rr = "albedo": of
   throughput x albedo; ``survival_probability``) and is divided by q (unbiased). The cap
   is 1 when max_depth bounds the path and RR_MAX_SURVIVAL when it does not, so that every
   path ends even with albedo 1 in an infinitely dense medium.
6. A new direction is importance-sampled from the phase function; go to 2.

Random numbers: stream STREAM_PATH for all decisions of the path (in the order above),
stream STREAM_SHADOW for all shadow-ray transmittance estimates of the sample.

Samplers (render.sampler): with "stratified" or "sobol" the decisions a path makes a fixed
number of times per bounce take their uniforms from the sampler (sampler.py) instead, each
from its own pair of dimensions (the SAMPLER_* layout in constants.py): the pixel position,
the lens position (a thin lens only), the hero channel, and for each of the first
SAMPLER_BOUNCES bounces the first uniform of the free flight (handed to the tracking loop by
rng_preset), the equiangular distances (one point per light), the environment directions
(one point per light sample: index s N + j, so a sample's N directions are consecutive
points of the pattern), Russian roulette and the phase direction. Everything else -- the
later tentative collisions of a flight, every transmittance estimate, bounces past
SAMPLER_BOUNCES -- comes from the counter RNG, whose count of draws varies from path to
path, so no fixed dimension could be assigned to it.
A sample whose contribution is NaN, infinite or negative is dropped (it counts as a sample
of value 0) and counted. Negative samples are legitimate only with a signed shadow estimator
(unbiased ray marching, params.signed_samples = 1): they are kept, since dropping them would
bias the pixel. RGB triples are tuples here and float3 in the kernel (vec.py).
"""

import math

import numpy as np
from numba import njit

from ..constants import (DENSITY_CONSTANT, EMISSION_SAMPLING_COLLISION, EMISSION_SAMPLING_MIS,
                         ENV_SAMPLING_IMPORTANCE, EQUIANGULAR_ALONE,
                         EQUIANGULAR_MIS, EQUIANGULAR_OFF, EVENT_CAPPED,
                         EVENT_ESCAPE, LIGHT_DIRECTIONAL, LIGHT_POINT, LIGHT_SPOT,
                         RECORD_CAMERA,
                         RECORD_SHADOW, RR_ALBEDO,
                         RR_MAX_SURVIVAL, SAMPLER_BOUNCES, SAMPLER_EQUIANGULAR,
                         SAMPLER_FIRST_BOUNCE, SAMPLER_FLIGHT, SAMPLER_INDEPENDENT,
                         SAMPLER_LIGHT, SAMPLER_PAIR_CHANNEL, SAMPLER_PAIR_LENS,
                         SAMPLER_PAIR_PIXEL, SAMPLER_PAIRS_PER_BOUNCE, SAMPLER_PHASE,
                         SPECTRAL_CHANNEL, SPECTRAL_GREY, SPECTRAL_HERO, STREAM_PATH, STREAM_SHADOW,
                         UNIFORM_SCALE)
from ..params import C_DROPPED, C_SCATTER, C_SHADOW, N_COUNTERS
from .camera import camera_ray
from .environment import env_radiance, environment_pdf, sample_environment
from .estimators import transmittance
from .free_flight import free_flight
from .guards import sample_ok
from .lights import (is_area_light, nearest_sphere, sample_area_light, spot_falloff,
                     sphere_light_pdf, sun_radiance)
from .medium import (ZERO, MediumData, extinction, has_medium, majorant_at, media_at,
                     media_emit, media_near, medium_chroma, medium_extinction, medium_pick,
                     ray_box, record_segment, to_medium, to_medium_dir)
from .phase import phase_eval, phase_sample
from .emitters import sample_emitter
from .tracking import EMIS_PLAIN, emission_term, mis_weights
from .rng import RNG_STATE_SIZE, rng_drop_preset, rng_init, rng_next, rng_preset
from .sampler import sampler_pair
from .sampling import (cone_pdf, dot, equiangular_pdf, mis_weight, mis_weight_over,
                       sample_equiangular, sample_uniform_sphere, uniform_sphere_pdf)
from .vec import add3, div3, madd3, max3, mul3, scale3

#: No albedo (the AOV of a camera ray that does not scatter; film.py).
ZERO3 = (0.0, 0.0, 0.0)


@njit(cache=True)
def enter_box(o, d, bmin, bmax):
    """Guard "entry re-basing" (robustness case 10, 11, 13): clip ray o + t d to the box and, when
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


@njit(cache=True)
def enter_medium(m, o, d):
    """enter_box for the medium's box, in its own space (to_medium): (origin, t0, t1, shift)
    as enter_box returns them, with the origin in the scene frame. A placed medium's origin
    moves along d to its entry point, snapped onto the face only in the medium's space."""
    if not m.transformed:
        return enter_box(o, d, (m.bmin[0], m.bmin[1], m.bmin[2]),
                         (m.bmax[0], m.bmax[1], m.bmax[2]))
    _, t0, t1, shift = enter_box(to_medium(m, o), to_medium_dir(m, d),
                                 (m.bmin[0], m.bmin[1], m.bmin[2]),
                                 (m.bmax[0], m.bmax[1], m.bmax[2]))
    if shift > 0.0:
        o = (o[0] + shift * d[0], o[1] + shift * d[1], o[2] + shift * d[2])
    return o, t0, t1, shift


@njit(cache=True)
def enter_media_near(med, o, d):
    """enter_medium for the scene's media: (origin, t0, t1, shift, near) of the segment of
    o + t d from where it enters the first box it meets to where it leaves the last; the
    origin moves (and snaps) onto the box it enters first, as enter_medium moves it. near:
    the media the ray comes near (media_near of the whole ray), for the walk that follows
    (majorant_iter_init_near)."""
    if len(med) == 1:
        o2, t0, t1, shift = enter_medium(med[0].m, o, d)
        return o2, t0, t1, shift, 1
    first = math.inf
    j = -1
    near = media_near(med, o, d, 0.0, math.inf)
    for i in range(len(med)):
        if not has_medium(near, i):   # (a ray that misses the near box misses the box)
            continue
        m = med[i].m
        te, tx = ray_box(to_medium(m, o), to_medium_dir(m, d), m.bmin, m.bmax)
        if tx > te and tx > 0.0 and te < first:
            first = te
            j = i
    o2, t0, t1, shift = o, 0.0, -math.inf, 0.0
    for i in range(len(med)):   # (an index Numba can type: see medium.ZERO)
        if i == j:
            o2, t0, _, shift = enter_medium(med[i].m, o, d)
    if j < 0:
        return o2, t0, t1, shift, near
    for i in range(len(med)):
        if not has_medium(near, i):
            continue
        m = med[i].m
        te, tx = ray_box(to_medium(m, o), to_medium_dir(m, d), m.bmin, m.bmax)
        if tx > te:
            t1 = max(t1, tx - shift)
    return o2, t0, t1, shift, near


@njit(cache=True)
def enter_media(med, o, d):
    """enter_media_near without the near set: (origin, t0, t1, shift)."""
    o2, t0, t1, shift, _ = enter_media_near(med, o, d)
    return o2, t0, t1, shift


@njit(cache=True)
def medium_albedo(med, i):
    """Medium i's single-scattering albedo, RGB."""
    a = med[i].m.albedo
    return (a[0], a[1], a[2])


@njit(cache=True)
def medium_phase_eval(med, i, d, w):
    """Medium i's phase function between the path's direction d and w (phase_eval)."""
    m = med[i].m
    return phase_eval(m.phase_kind, m.g, d, w)


@njit(cache=True)
def medium_phase_sample(med, i, u1, u2, d_in):
    """A direction from medium i's phase function about d_in, and its pdf."""
    m = med[i].m
    return phase_sample(m.phase_kind, m.g, u1, u2, d_in)


@njit(cache=True)
def in_scattering(med, p, d, w, counters):
    """Light scattered at p from the ray's direction d into w by every medium there: the sum
    of sigma_s f(d, w) over the media, RGB, with a counted lookup per medium present."""
    k = medium_chroma(med)
    out = (0.0, 0.0, 0.0)
    here = media_at(med, p)
    for i in range(len(med)):
        m = med[i].m
        if not has_medium(here, i):
            continue
        mu = medium_extinction(med, i, p, counters)
        f = phase_eval(m.phase_kind, m.g, d, w)
        out = add3(out, (m.albedo[0] * (k[0] * mu) * f, m.albedo[1] * (k[1] * mu) * f,
                         m.albedo[2] * (k[2] * mu) * f))
    return out


@njit(cache=True)
def keep_carried(beta, x):
    """x with the components where beta is 0 set to 0 (RGB)."""
    return (x[0] if beta[0] != 0.0 else 0.0, x[1] if beta[1] != 0.0 else 0.0,
            x[2] if beta[2] != 0.0 else 0.0)


@njit(cache=True)
def shadow_transmittance(prm, med, o, d, t_max, view, rng_s, counters):
    """Transmittance (RGB) from o towards unit d up to distance t_max (inf for distant
    lights), by the estimator render.transmittance chose: prm.shadow_estimator for the
    shadow rays of scattering paths (view = 0), prm.view_estimator for camera rays that
    cannot scatter (view = 1), whose transmittance is the sample. They differ only for
    "auto" (techniques.py)."""
    o, t0, t1, shift = enter_media(med, o, d)
    t1 = min(t1, t_max - shift)
    if t1 <= t0:
        return (1.0, 1.0, 1.0)
    record_segment(med, o, d, t0, t1, RECORD_SHADOW)
    counters[C_SHADOW] += 1
    return transmittance(prm.view_estimator if view else prm.shadow_estimator, med, o, d, t0,
                         t1, rng_s, counters, prm.max_steps)


@njit(cache=True)
def bounce_pair(b, offset):
    """The sample pair ``offset`` (SAMPLER_FLIGHT, ...) of bounce b, or -1 past
    SAMPLER_BOUNCES (those bounces use the counter RNG)."""
    if b >= SAMPLER_BOUNCES:
        return -1
    return SAMPLER_FIRST_BOUNCE + b * SAMPLER_PAIRS_PER_BOUNCE + offset


@njit(cache=True)
def path_pair_u24(prm, pix, s, pair, j, count):
    """The render.sampler's pair ``pair`` of sample s of pixel pix as two 24-bit integers;
    the j-th of ``count`` points the sample takes from it (index s count + j, stratified over
    spp count points). Callers pass int(...) of constants: Numba compiles a callee once per
    literal argument value, and the sampler's inlined maths made each compile cost seconds."""
    return sampler_pair(prm.sampler, prm.seed_lo, prm.seed_hi, pix,
                        (s * count + j) & 0xFFFFFFFF, pair, (prm.spp * count) & 0xFFFFFFFF)


@njit(cache=True)
def path_u2(prm, pix, s, pair, j, count, rng):
    """Two uniforms of pair ``pair`` (see path_pair_u24): from the counter RNG when the
    sampler is independent or pair < 0."""
    if prm.sampler == SAMPLER_INDEPENDENT or pair < 0:
        u1 = rng_next(rng)
        return u1, rng_next(rng)
    a, b = path_pair_u24(prm, pix, s, int(pair), int(j), int(count))
    return float(a) * UNIFORM_SCALE, float(b) * UNIFORM_SCALE


@njit(cache=True)
def path_u1(prm, pix, s, pair, axis, j, count, rng):
    """One uniform: coordinate ``axis`` (0: x, 1: y) of pair ``pair``, or one draw of the
    counter RNG."""
    if prm.sampler == SAMPLER_INDEPENDENT or pair < 0:
        return rng_next(rng)
    a, b = path_pair_u24(prm, pix, s, int(pair), int(j), int(count))
    return float(b if axis == 1 else a) * UNIFORM_SCALE


@njit(cache=True)
def equiangular_mode(prm, med):
    """EQUIANGULAR_OFF, _ALONE or _MIS for the scene (see the constants): MIS needs free
    flight's density in closed form, so one homogeneous grey medium."""
    if prm.equiangular == 0:
        return EQUIANGULAR_OFF
    m = med[0].m
    if len(med) == 1 and m.density_kind == DENSITY_CONSTANT and m.spectral == SPECTRAL_GREY:
        return EQUIANGULAR_MIS
    return EQUIANGULAR_ALONE


@njit(cache=True)
def direction_to(p, c):
    """(unit direction from p to c, distance |c - p|); the distance is 0 when p = c."""
    v = (c[0] - p[0], c[1] - p[1], c[2] - p[2])
    dist = math.sqrt(dot(v, v))
    if not dist > 0.0:
        return v, 0.0
    return (v[0] / dist, v[1] / dist, v[2] / dist), dist


@njit(cache=True)
def foot_on_ray(c, o, d):
    """(h, D): ray parameter of point c's foot on the ray o + t d (unit d), and c's distance
    from the ray's line (world units)."""
    v = (c[0] - o[0], c[1] - o[1], c[2] - o[2])
    h = dot(v, d)
    w = (v[0] - h * d[0], v[1] - h * d[1], v[2] - h * d[2])
    return h, math.sqrt(dot(w, w))


@njit(cache=True)
def free_flight_pdf(m, t0, t):
    """Density of free flight's first real collision at t in a homogeneous grey medium
    entered at t0: sigma e^{-sigma (t - t0)} per world unit."""
    s = m.scale * m.density
    return s * math.exp(-s * (t - t0))


@njit(cache=True)
def point_light_nee_weight(prm, m, ea, c, o, d, t0, t1, t):
    """MIS weight of next-event estimation towards point light c at the free-flight vertex
    o + t d of segment [t0, t1]: 1 without equiangular sampling, and also when c lies on the
    segment's line (equiangular sampling samples nothing there); 0 when equiangular
    sampling alone covers the light; else the heuristic against the equiangular pdf."""
    if ea == EQUIANGULAR_OFF:
        return 1.0
    h, D = foot_on_ray(c, o, d)
    if not D > 0.0:
        return 1.0
    if ea == EQUIANGULAR_ALONE:
        return 0.0
    return mis_weight(prm.mis, free_flight_pdf(m, t0, t), equiangular_pdf(t, h, D, t0, t1))


@njit(cache=True)
def light_ray(prm, m, ea, lt, o, d, t0, t1, t):
    """The ray of next-event estimation towards delta light lt (a parallel directional
    light, a point or a spot) from the vertex p = o + t d of segment [t0, t1]. Returns (wl,
    dist, falloff): the unit direction, the distance (inf for a directional light) and the
    falloff (1, or a point light's MIS weight over the squared distance, times a spot's
    spot_falloff); falloff 0: this light sends nothing to p (it sits at p, p is outside its
    cone, or equiangular sampling alone covers it)."""
    if lt.type == LIGHT_DIRECTIONAL:
        return (-lt.vec[0], -lt.vec[1], -lt.vec[2]), math.inf, 1.0
    c = (lt.vec[0], lt.vec[1], lt.vec[2])
    wl, dist = direction_to(madd3(o, d, t), c)
    if not dist > 0.0:
        return wl, dist, 0.0
    f = point_light_nee_weight(prm, m, ea, c, o, d, t0, t1, t) / (dist * dist)
    if lt.type == LIGHT_SPOT:
        f *= spot_falloff(lt, wl)
    return wl, dist, f


@njit(cache=True)
def light_point(prm, i, j):
    """(index, count) for path_u2 of the j-th of the N = render.light_samples directions
    light i samples (i = n_lights: the environment) from the light pair: the environment's
    N alone when no light samples a direction (the layout of scenes without area lights),
    else N points per light, the environment's last."""
    n = prm.light_samples
    if prm.area_lights == 0:
        return j, n
    return i * n + j, (prm.n_lights + 1) * n


@njit(cache=True)
def occluded(prm, lights, p, w, dist, target):
    """True when a sphere light other than ``target`` (-1: none) blocks the ray from p along
    w before distance dist (inf: the sky)."""
    if prm.spheres == 0:
        return False
    t, i = nearest_sphere(prm, lights, p, w)
    return i >= 0 and i != target and t < dist


@njit(cache=True)
def escape_weight(prm, depth, pdf_phase, n_pdf_light):
    """Weight of light a ray sees where light sampling could also have found it: 1 for a
    camera ray (0 for the sky with render.transparent_background), the heuristic
    render.mis of phase sampling's pdf against light sampling's N p for a scattered one."""
    if depth > 0:
        return mis_weight(prm.mis, pdf_phase, n_pdf_light)
    return 0.0 if prm.transparent != 0 else 1.0


@njit(cache=True)
def escape_light(prm, lights, env, d, pdf_phase, depth):
    """Radiance a ray that escapes along d sees in the sky: the environment and every sun
    disc whose cone holds d, each weighted by escape_weight (``depth``: scattering events
    before the ray, ``pdf_phase``: the density phase sampling chose d with)."""
    n = prm.light_samples
    L = (0.0, 0.0, 0.0)
    if prm.has_env != 0:
        L = scale3(env_light(prm, env, d), escape_weight(prm, depth, pdf_phase,
                                                          n * env_light_pdf(prm, env, d)))
    if prm.area_lights > 0:
        for i in range(prm.n_lights):
            lt = lights[i]
            if lt.type != LIGHT_DIRECTIONAL or not lt.size > 0.0:
                continue
            pdf_l = cone_pdf(d, (-lt.vec[0], -lt.vec[1], -lt.vec[2]), lt.size)
            if pdf_l > 0.0:
                w = escape_weight(prm, depth, pdf_phase, n * pdf_l) * sun_radiance(lt)
                L = add3(L, scale3((lt.color[0], lt.color[1], lt.color[2]), w))
    return L


@njit(cache=True)
def env_light(prm, env, w):
    """The environment's radiance from scene direction w: its map's (environment.py) or the
    constant prm.env."""
    if prm.env_map != 0:
        return env_radiance(prm, env, w)
    return (prm.env[0], prm.env[1], prm.env[2])


@njit(cache=True)
def sample_env_light(prm, env, u1, u2):
    """A direction for the environment's shadow rays: from the map's density (render.
    env_sampling = "importance") or uniform over the sphere. Returns (w, pdf per sr)."""
    if prm.env_map != 0 and prm.env_sampling == ENV_SAMPLING_IMPORTANCE:
        return sample_environment(prm, env, u1, u2)
    return sample_uniform_sphere(u1, u2)


@njit(cache=True)
def env_light_pdf(prm, env, w):
    """Density per steradian of ``sample_env_light`` at scene direction w."""
    if prm.env_map != 0 and prm.env_sampling == ENV_SAMPLING_IMPORTANCE:
        return environment_pdf(prm, env, w)
    return uniform_sphere_pdf()


@njit(cache=True)
def sample_direct(prm, lights, env, med, k, ea, o, d, t0, t1, t, pix, s, b, rng, rng_s,
                  counters):
    """Direct light scattered at p = o + t d towards -d, per unit throughput (RGB). The
    vertex was reached by free flight along segment [t0, t1] of the ray o + t d (unit d: the
    direction the path arrived in); ``ea`` is equiangular_mode; (pix, s, b): pixel, sample and
    bounce of the segment, for render.sampler.

    render.light_samples = N: every delta light (parallel, point, spot) gets N shadow rays,
    each with its own transmittance estimate, averaged (splitting); every area light (sun
    disc, sphere; lights.py) and the environment N sampled directions, each weighted by the
    heuristic render.mis against phase sampling with the sample counts in it
    (w = N p_l / (N p_l + p_phase) for the balance heuristic; the phase-sampled path that
    meets the light gets the complement). A point light's estimate is weighted against
    equiangular sampling (point_light_nee_weight). A sphere light between p and a light
    blocks the ray (occluded), before any transmittance is estimated. The vertex scattered in
    medium k, whose phase function weighs the lights."""
    p = madd3(o, d, t)
    n = prm.light_samples
    inv_n = 1.0 / n
    pair = bounce_pair(b, SAMPLER_LIGHT)
    L = (0.0, 0.0, 0.0)
    for i in range(prm.n_lights):
        lt = lights[i]
        color = (lt.color[0], lt.color[1], lt.color[2])
        if is_area_light(lt):
            for j in range(n):
                ja, count = light_point(prm, i, j)
                ua, ub = path_u2(prm, pix, s, pair, ja, count, rng)
                wl, dist, pdf_l, le = sample_area_light(lt, p, ua, ub)
                if not pdf_l > 0.0 or occluded(prm, lights, p, wl, dist, i):
                    continue
                f = medium_phase_eval(med, k, d, wl)
                g = f * le * mis_weight(prm.mis, n * pdf_l, f) * inv_n / pdf_l
                tr = shadow_transmittance(prm, med, p, wl, dist, 0, rng_s, counters)
                L = add3(L, mul3(color, scale3(tr, g)))
            continue
        wl, dist, falloff = light_ray(prm, med[0].m, ea, lt, o, d, t0, t1, t)
        if not falloff > 0.0 or occluded(prm, lights, p, wl, dist, -1):
            continue
        f = medium_phase_eval(med, k, d, wl) * falloff * inv_n
        for _ in range(n):
            tr = shadow_transmittance(prm, med, p, wl, dist, 0, rng_s, counters)
            L = add3(L, mul3(color, scale3(tr, f)))
    if prm.has_env != 0:
        for j in range(n):
            ja, count = light_point(prm, prm.n_lights, j)
            ua, ub = path_u2(prm, pix, s, pair, ja, count, rng)
            wl, pdf_l = sample_env_light(prm, env, ua, ub)
            if occluded(prm, lights, p, wl, math.inf, -1):
                continue
            f = medium_phase_eval(med, k, d, wl)
            tr = shadow_transmittance(prm, med, p, wl, math.inf, 0, rng_s, counters)
            w = mis_weight(prm.mis, n * pdf_l, f) * inv_n
            # (pdf 0: a pole of the map, a set of measure zero; the ray carries nothing)
            g = f * w / pdf_l if pdf_l > 0.0 else 0.0
            L = add3(L, mul3(env_light(prm, env, wl), scale3(tr, g)))
    if prm.emission_sampling != EMISSION_SAMPLING_COLLISION:
        L = add3(L, sample_emitters(prm, lights, med, k, p, d, rng, counters, rng_s))
    return L


@njit(cache=True)
def sample_emitters(prm, lights, med, k, p, d, rng, counters, rng_s):
    """Emission sampling (render.emission_sampling "light" or "mis"; emitters.py) at the
    vertex p, where the path arrived along d and scatters in medium k: light_samples points
    y drawn in the emitting media (five uniforms each from the path stream), each adding

        f(d . w) T(p, y) sigma_a(y) Le(y) w_L / (N pdf(y) |y - p|^2),

    per unit throughput (RGB), T estimated as every shadow ray's. w_L is 1 with "light",
    else the heuristic render.mis of N pdf(y) against f sigma_maj(y) / |y - p|^2
    (tracking.emission_weight, which weighs the flights with the complement). sigma_a Le sums every medium's; a sphere light between p and y
    blocks it; a point with no emission draws no shadow ray."""
    n = prm.light_samples
    L = (0.0, 0.0, 0.0)
    for _ in range(n):
        u0 = rng_next(rng)
        u1 = rng_next(rng)
        u2 = rng_next(rng)
        u3 = rng_next(rng)
        u4 = rng_next(rng)
        y, pdf = sample_emitter(med, u0, u1, u2, u3, u4)
        if not pdf > 0.0:
            continue
        wl, dist = direction_to(p, y)
        if not dist > 0.0:
            continue
        mu = extinction(med, y, math.inf, counters) if len(med) == 1 else 0.0
        src = emission_term(med, media_at(med, y), y, mu, 1.0, (1.0, 1.0, 1.0), counters)
        if not max3(src) > 0.0 or occluded(prm, lights, p, wl, dist, -1):
            continue
        f = medium_phase_eval(med, k, d, wl)
        # f w / (n pdf dist^2), the two densities in 1/sr times dist^2: the weight and the
        # 1/dist^2 cancel, so a sample next to its vertex in a dense emitter stays finite.
        q = n * pdf * dist * dist
        if prm.emission_sampling == EMISSION_SAMPLING_MIS:
            g = f * mis_weight_over(prm.mis, q, f * majorant_at(med, y))
        else:
            g = f / q
        tr = shadow_transmittance(prm, med, p, wl, dist, 0, rng_s, counters)
        L = add3(L, mul3(src, scale3(tr, g)))
    return L


@njit(cache=True)
def sample_equiangular_lights(prm, lights, med, ea, o, d, t0, t1, pix, s, b, rng, rng_s,
                              counters):
    """Light from every point and spot light scattered once inside segment [t0, t1] of the
    ray o + t d towards -d, per unit throughput at o (RGB), by equiangular sampling: one distance
    t per light from the equiangular pdf (one uniform of the path stream each), and

        sigma_s(t) T(t0, t) phase f I T_light(t) / r(t)^2 / pdf(t),

    with T(t0, t) and T_light unbiased estimates of render.transmittance (exact in a
    homogeneous medium), so the estimate stays unbiased in any medium. Weighted against
    free flight's next-event estimate by MIS when ``ea`` is EQUIANGULAR_MIS. Several media:
    sigma_s f is the sum over the media at the sampled point (in_scattering)."""
    m = med[0].m
    L = (0.0, 0.0, 0.0)
    for i in range(prm.n_lights):
        lt = lights[i]
        if lt.type != LIGHT_POINT and lt.type != LIGHT_SPOT:
            continue
        u = path_u1(prm, pix, s, bounce_pair(b, SAMPLER_EQUIANGULAR), 0, i, prm.n_lights, rng)
        c = (lt.vec[0], lt.vec[1], lt.vec[2])
        h, D = foot_on_ray(c, o, d)
        if not D > 0.0:
            continue   # the light is on the line: next-event estimation covers it
        t, pdf = sample_equiangular(u, h, D, t0, t1)
        if not pdf > 0.0:
            continue
        p = madd3(o, d, t)
        wl, dist = direction_to(p, c)
        if not dist > 0.0:
            continue
        spot = spot_falloff(lt, wl) if lt.type == LIGHT_SPOT else 1.0
        if not spot > 0.0 or occluded(prm, lights, p, wl, dist, -1):
            continue
        if len(med) == 1:
            sig = scale3(medium_chroma(med), extinction(med, p, math.inf, counters))
            sig_s = mul3(sig, (m.albedo[0], m.albedo[1], m.albedo[2]))
        else:   # sigma_s times the phase function, summed over the media at p
            sig_s = in_scattering(med, p, d, wl, counters)
        if max3(sig_s) <= 0.0:
            continue
        counters[C_SHADOW] += 1
        t_cam = transmittance(prm.shadow_estimator, med, o, d, t0, t, rng_s, counters,
                              prm.max_steps)
        t_lt = shadow_transmittance(prm, med, p, wl, dist, 0, rng_s, counters)
        w = 1.0
        if ea == EQUIANGULAR_MIS:
            w = mis_weight(prm.mis, pdf, free_flight_pdf(m, t0, t))
        f = w / (dist * dist * pdf)
        if len(med) == 1:
            f = phase_eval(m.phase_kind, m.g, d, wl) * w / (dist * dist * pdf)
        L = add3(L, mul3((lt.color[0], lt.color[1], lt.color[2]),
                         scale3(mul3(sig_s, mul3(t_cam, t_lt)), f * spot)))
    return L


@njit(cache=True)
def survival_probability(prm, beta_w, albedo):
    """Russian roulette's survival probability q (render.rr): the largest channel of the
    throughput ("throughput"), or of the throughput the path will carry after its next
    scattering, throughput x albedo ("albedo": the expected contribution of going on),
    capped at 1, or at RR_MAX_SURVIVAL when the depth is unbounded (max_depth = -1), so
    that every path ends. Survivors are divided by q; in the general form
    F' = (F - (1 - q) c) / q for survivors and c for the rest, volmc uses c = 0."""
    cap = RR_MAX_SURVIVAL if prm.max_depth < 0 else 1.0
    if prm.rr == RR_ALBEDO:
        return min(max3(mul3(beta_w, albedo)), cap)
    return min(max3(beta_w), cap)


@njit(cache=True)
def coverage(T):
    """A = 1 - T of a camera ray's transmittance estimate T (RGB): 1 - the channels' mean."""
    return 1.0 - (T[0] + T[1] + T[2]) / 3.0


@njit(cache=True)
def trace_path(prm, lights, env, med, px, py, s, rng, rng_s, counters):
    """(r, g, b, a, albedo): the radiance carried by sample s of pixel (px, py), its
    coverage a = coverage(T), T the camera ray's transmittance to the background as this path
    estimates it: the weight of its first flight's escape (0 when it scatters or is capped,
    1 when the ray misses the medium), or the transmittance estimate of a scene that cannot
    scatter; and its albedo AOV (film.py): the albedo of the medium the camera ray first
    scatters in, else (0, 0, 0). With prm.transparent the camera ray does not see the
    environment."""
    m = med[0].m
    top = 0.0   # the largest albedo of any medium
    for i in range(len(med)):
        top = max(top, max3(medium_albedo(med, i)))
    L = (0.0, 0.0, 0.0)
    beta = (1.0, 1.0, 1.0)
    pix = py * prm.width + px
    u1, u2 = path_u2(prm, pix, s, SAMPLER_PAIR_PIXEL, 0, 1, rng)
    v1, v2 = 0.5, 0.5   # a pinhole draws no lens sample, so its paths are unchanged
    if prm.aperture > 0.0:
        v1, v2 = path_u2(prm, pix, s, SAMPLER_PAIR_LENS, 0, 1, rng)
    o, d = camera_ray(prm, px, py, u1, u2, v1, v2)
    if (prm.max_depth == 0 or top <= 0.0) and not media_emit(med):
        # No scattering can contribute: the pixel is the environment seen through the
        # medium, so estimate the transmittance instead of sampling a collision (exact for
        # a homogeneous medium, lower variance than a 0/1 free-flight outcome for grids).
        t_hit, hit = math.inf, -1
        if prm.spheres != 0:
            t_hit, hit = nearest_sphere(prm, lights, o, d)
        T = shadow_transmittance(prm, med, o, d, t_hit, 1, rng_s, counters)
        if hit >= 0:   # an opaque sphere light: it covers the pixel
            lt = lights[hit]
            L = mul3((lt.color[0], lt.color[1], lt.color[2]), T)
            return L[0], L[1], L[2], 1.0, ZERO3
        if prm.has_env != 0 or prm.area_lights > 0:
            L = mul3(escape_light(prm, lights, env, d, 0.0, 0), T)
        return L[0], L[1], L[2], coverage(T), ZERO3
    hero = -1
    R = (1.0, 1.0, 1.0)   # hero MIS: each channel's decision probability over the hero's
    if m.spectral == SPECTRAL_CHANNEL or m.spectral == SPECTRAL_HERO:
        # A channel per path, chosen uniformly: alone (render.spectral = "channel", the
        # baseline) or as the hero of spectral MIS ("hero").
        c = min(int(path_u1(prm, pix, s, SAMPLER_PAIR_CHANNEL, 0, 0, 1, rng) * 3.0), 2)
        if m.spectral == SPECTRAL_HERO:
            hero = c
        else:
            beta = (3.0 if c == 0 else 0.0, 3.0 if c == 1 else 0.0, 3.0 if c == 2 else 0.0)
    depth = 0
    pdf_phase = 0.0  # pdf of the direction d when it came from phase sampling
    ea = equiangular_mode(prm, med)
    k = ZERO   # the medium the path scattered in last
    alpha = 0.0
    aov = ZERO3
    while True:
        t_hit, hit, pdf_hit = math.inf, -1, 0.0   # the sphere light the ray meets first
        if prm.spheres != 0:
            t_hit, hit = nearest_sphere(prm, lights, o, d)
            if hit >= 0:   # its pdf for MIS, from the vertex before the box moves it
                pdf_hit = sphere_light_pdf(lights[hit], o, d, t_hit)
        o, t0, t1, shift = enter_media(med, o, d)
        t1 = min(t1, t_hit - shift)
        if depth == 0 and not t1 > t0 and m.spectral == SPECTRAL_CHANNEL:
            # A camera ray that meets no medium sees the same light in every channel: its
            # path carries all three, not 3x one (unbiased either way: E[3 e_c] = 1; the
            # background was noise around the sky's colour).
            beta = (1.0, 1.0, 1.0)
        event = EVENT_ESCAPE
        t = t1
        if t1 > t0:
            if depth == 0:
                record_segment(med, o, d, t0, t1, RECORD_CAMERA)
            if ea != EQUIANGULAR_OFF and (prm.max_depth < 0 or depth < prm.max_depth):
                beta_w = mul3(beta, mis_weights(R)) if hero >= 0 else beta
                L = add3(L, mul3(beta_w, sample_equiangular_lights(
                    prm, lights, med, ea, o, d, t0, t1, pix, s, depth, rng, rng_s, counters)))
            pair = bounce_pair(depth, SAMPLER_FLIGHT)
            if prm.sampler != SAMPLER_INDEPENDENT and pair >= 0:
                rng_preset(rng, path_pair_u24(prm, pix, s, pair, int(0), int(1))[0])
            emis = EMIS_PLAIN
            if prm.emission_sampling != EMISSION_SAMPLING_COLLISION and depth > 0:
                emis = (pdf_phase if prm.emission_sampling == EMISSION_SAMPLING_MIS else 0.0,
                        shift, float(prm.light_samples), float(prm.mis))
            if hero >= 0:
                event, t, w, E = free_flight(med, o, d, t0, t1, prm.decomposition != 0, R,
                                             hero, emis, rng, counters, prm.max_steps)
                L = add3(L, mul3(beta, E))
                R = mul3(R, w)
                R = scale3(R, 1.0 / max3(R)) if max3(R) > 0.0 else R   # ratios only
            else:
                event, t, w, E = free_flight(med, o, d, t0, t1, prm.decomposition != 0, beta,
                                             -1, emis, rng, counters, prm.max_steps)
                # Channels the path no longer carries stay 0, whatever their weight grew to
                # (one channel per path: 0 x inf would be NaN).
                L = add3(L, mul3(beta, keep_carried(beta, E)))
                beta = mul3(beta, keep_carried(beta, w))
            rng_drop_preset(rng)
        # The throughput every contribution is weighed by: with hero MIS, the balance
        # heuristic's weights on top of the common factors.
        beta_w = mul3(beta, mis_weights(R)) if hero >= 0 else beta
        if depth == 0:
            alpha = coverage(beta_w) if event == EVENT_ESCAPE and hit < 0 else 1.0
        if event == EVENT_CAPPED:
            break
        if event == EVENT_ESCAPE:
            if hit >= 0:   # the sphere light ends the ray
                lt = lights[hit]
                w = 1.0 if depth == 0 else \
                    mis_weight(prm.mis, pdf_phase, prm.light_samples * pdf_hit)
                L = add3(L, mul3(beta_w, scale3((lt.color[0], lt.color[1], lt.color[2]), w)))
            elif prm.has_env != 0 or prm.area_lights > 0:
                L = add3(L, mul3(beta_w, escape_light(prm, lights, env, d, pdf_phase, depth)))
            break
        depth += 1
        if prm.max_depth >= 0 and depth > prm.max_depth:
            break
        counters[C_SCATTER] += 1
        k = medium_pick(med, madd3(o, d, t), rng, counters)
        albedo = medium_albedo(med, k)
        if depth == 1:
            aov = albedo
        beta = mul3(beta, albedo)
        beta_w = mul3(beta_w, albedo)
        if max3(beta_w) <= 0.0:
            break
        L = add3(L, mul3(beta_w, sample_direct(prm, lights, env, med, k, ea, o, d, t0, t1, t,
                                               pix, s, depth - 1, rng, rng_s, counters)))
        p = madd3(o, d, t)
        if depth >= prm.rr_depth:
            q = survival_probability(prm, beta_w, albedo)
            if path_u1(prm, pix, s, bounce_pair(depth - 1, SAMPLER_FLIGHT), 1, 0, 1, rng) >= q:
                break
            beta = div3(beta, q)
        u1, u2 = path_u2(prm, pix, s, bounce_pair(depth - 1, SAMPLER_PHASE), 0, 1, rng)
        d, pdf_phase = medium_phase_sample(med, k, u1, u2, d)
        o = p
    return L[0], L[1], L[2], alpha, aov


@njit(cache=True)
def render_pixel(params, lights, env, media, rec, pix, sample_start, n_samples, film_sum,
                 film_sq, cnt):
    """Add samples [sample_start, sample_start + n_samples) of pixel ``pix`` to the film;
    ``rec``: the pixel's segment record [K + 1, 9] or the [1, 9] placeholder (the first
    medium's record becomes it); ``cnt``: the pixel's counters [N_COUNTERS], accumulated in
    place."""
    prm = params[0]
    a = media[0]
    med = (MediumData(a.m, a.grid, a.maj, a.mnr, a.emis, a.table, a.bricks, a.pool, a.nodes,
                      rec),) + media[1:]
    py = pix // prm.width
    px = pix - py * prm.width
    seed = (np.uint64(prm.seed_hi) << np.uint64(32)) | np.uint64(prm.seed_lo)
    rng = np.empty(RNG_STATE_SIZE, np.uint32)
    rng_s = np.empty(RNG_STATE_SIZE, np.uint32)
    sr = 0.0
    sg = 0.0
    sb = 0.0
    sa = 0.0
    qr = 0.0
    qg = 0.0
    qb = 0.0
    qa = 0.0
    aov_sum = ZERO3
    aov_sq = ZERO3
    for s in range(sample_start, sample_start + n_samples):
        rng_init(rng, seed, pix, s, STREAM_PATH)
        rng_init(rng_s, seed, pix, s, STREAM_SHADOW)
        r, g, b, a, aov = trace_path(prm, lights, env, med, px, py, s, rng, rng_s, cnt)
        if not sample_ok(r, g, b, prm.signed_samples):
            # The sample counts as 0 in every channel (guard "sample filter", guards.py).
            cnt[C_DROPPED] += 1
            continue
        sr += r
        sg += g
        sb += b
        sa += a
        qr += r * r
        qg += g * g
        qb += b * b
        qa += a * a
        aov_sum = add3(aov_sum, aov)
        aov_sq = add3(aov_sq, mul3(aov, aov))
    film_sum[py, px, 0] += sr
    film_sum[py, px, 1] += sg
    film_sum[py, px, 2] += sb
    film_sum[py, px, 3] += sa
    film_sq[py, px, 0] += qr
    film_sq[py, px, 1] += qg
    film_sq[py, px, 2] += qb
    film_sq[py, px, 3] += qa
    if film_sum.shape[2] > 4:   # the albedo AOV (film.py)
        for c in range(3):
            film_sum[py, px, 4 + c] += aov_sum[c]
            film_sq[py, px, 4 + c] += aov_sq[c]


@njit(cache=True, nogil=True)
def render_batch(params, lights, env, media, rec, pix_start, n_pix, sample_start, n_samples,
                 film_sum, film_sq, counters):
    """Add samples [sample_start, sample_start + n_samples) of pixels [pix_start, pix_start +
    n_pix) (row-major pixel indices; a band of rows, or every pixel) to the film.

    params: one-element array of ``params_dtype(float64)``; lights: array of
    ``light_dtype(float64)``; env: the environment map's ``EnvMap`` (environment.py;
    ``no_env()`` without one); media: a tuple of ``MediumData``, one per medium (``media_data``
    in medium.py; their ``rec`` is a placeholder), whose record is a ``medium_dtype(float64)``
    record and whose arrays are: grid:
    float64 [nz, ny, nx] density (a 1x1x1 placeholder unless the density is a grid); maj,
    mnr: per-cell density bounds [cz, cy, cx] of the majorant grid (per node, [1, 1, n], of
    an octree); emis: float64 emission
    field grid [nz, ny, nx]; table: the blackbody table [BLACKBODY_TABLE_SIZE, 3] (1x1x1 and
    2x3 placeholders without emission); bricks, pool: a brick grid's index table int32
    [bz, by, bx] and pool [n_slots, 8, 8, 8] (placeholders unless the density is bricks);
    nodes: an octree's int32 first-child indices [n_nodes] (reference/octree.py; a
    placeholder without one); rec: the segment record [width * height, K + 1, 9] (record_segment in
    medium.py; row 0 of each pixel holds its count and the capacity K), or a [1, 1, 9]
    placeholder when not recording;
    film_sum, film_sq:
    float64 [height, width, 4] (RGBA) running sums of sample values and of their squares;
    counters: int64 [n_pix, N_COUNTERS], the launch's pixels (row i: pixel pix_start + i),
    accumulated in place. A pixel's samples depend on its index alone, so any split into
    bands gives the same image. Pixels are independent: the backend runs pixel ranges on
    threads (nogil; Numba's parallel loops cannot take the media tuple).
    """
    for i in range(n_pix):
        pix = pix_start + i
        rp = rec[pix] if rec.shape[1] > 1 else rec[0]
        render_pixel(params, lights, env, media, rp, pix, sample_start, n_samples, film_sum,
                     film_sq, counters[i])


def new_counters(width, height):
    """Zeroed per-pixel counter array for ``render_batch``."""
    return np.zeros((width * height, N_COUNTERS), np.int64)
