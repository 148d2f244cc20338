"""Lights that are not the environment: what each sends to a point, how next-event
estimation samples the ones with extent, and where a ray meets a sphere light. Twin of
``kernels/lights.h``.

The light record is params.LIGHT_FIELDS, in the scene frame (pack.py):

* **directional**: ``vec`` the propagation direction, ``color`` the irradiance E on a
  surface facing the light. ``size`` = omc = 1 - cos theta_max, theta_max half the apex
  angle: 0 is parallel light (a delta direction); omc > 0 is a sun disc of uniform radiance
  E / (pi sin^2 theta_max) = E / (pi omc (2 - omc)) over the cone about -vec, so that the
  irradiance at normal incidence stays E. It is sampled uniformly in its cone, and a ray
  that escapes inside the cone sees it (camera rays too).
* **point**: ``vec`` the position, ``color`` the intensity I (per steradian): I / r^2.
* **spot**: a point light whose intensity is ``color`` x spot_falloff, the falloff a
  smoothstep in cos theta (theta from the unit ``axis``) from ``size`` = cos of the
  half-angle (0) to ``inner`` (1). blend = 0 makes inner = size: a hard edge.
* **sphere**: ``vec`` the centre, ``size`` the radius r, ``color`` the radiance L of its
  surface, the same on both sides; the sphere is opaque. From outside it is sampled
  uniformly in the cone of directions that meet it (sin theta_max = r / |c - p|); from
  inside by area (pdf dist^2 / (4 pi r^2 |cos|) per steradian). Its power is
  4 pi^2 r^2 L; far away it is a point light of intensity pi r^2 L.
"""

import math

from numba import njit

from ..constants import INV_4PI, LIGHT_DIRECTIONAL, LIGHT_SPHERE, PI
from .sampling import cone_pdf, dot, sample_cone, sample_uniform_sphere


@njit(cache=True)
def is_area_light(lt):
    """True for a light next-event estimation samples a direction of: a sun disc or a
    sphere (their shadow rays take uniforms; delta lights take none)."""
    return lt.type == LIGHT_SPHERE or (lt.type == LIGHT_DIRECTIONAL and lt.size > 0.0)


@njit(cache=True)
def sun_radiance(lt):
    """Radiance of sun disc lt per unit of its irradiance: 1 / (pi omc (2 - omc))."""
    omc = lt.size
    return 1.0 / (PI * omc * (2.0 - omc))


@njit(cache=True)
def spot_falloff(lt, wl):
    """Spot lt's intensity factor towards a point that sees it in unit direction wl:
    smoothstep of cos theta = -wl . axis between cos(angle) (0) and ``inner`` (1)."""
    cos_t = -dot(wl, (lt.axis[0], lt.axis[1], lt.axis[2]))
    if cos_t <= lt.size:
        return 0.0
    if cos_t >= lt.inner:
        return 1.0
    x = (cos_t - lt.size) / (lt.inner - lt.size)
    return x * x * (3.0 - 2.0 * x)


@njit(cache=True)
def sphere_hit(lt, o, d):
    """Distance t > 0 along the ray o + t d (unit d) where it first meets sphere light lt;
    inf if it does not. The discriminant is r^2 - |v - (v.d) d|^2 (v = o - c), which keeps
    its digits for a small sphere far away, and the near root is c / q, no cancellation."""
    v = (o[0] - lt.vec[0], o[1] - lt.vec[1], o[2] - lt.vec[2])
    r = lt.size
    b = dot(v, d)
    f = (v[0] - b * d[0], v[1] - b * d[1], v[2] - b * d[2])
    disc = r * r - dot(f, f)
    if disc < 0.0:
        return math.inf
    sq = math.sqrt(disc)
    cc = dot(v, v) - r * r
    if cc > 0.0:   # outside: the near root, when the sphere is ahead
        if b >= 0.0:
            return math.inf
        return cc / (sq - b)
    t = sq - b   # inside (or on it): the far root
    return t if t > 0.0 else math.inf


@njit(cache=True)
def sphere_cone(lt, p):
    """(axis, omc, inside) of sphere light lt seen from p: the unit direction to its centre
    and 1 - cos theta_max of the cone it fills, written s2 / (1 + sqrt(1 - s2)) with
    s2 = sin^2 theta_max = r^2 / |c - p|^2 (no cancellation for a small sphere); inside: p
    is not outside the sphere (axis and omc are then meaningless)."""
    v = (lt.vec[0] - p[0], lt.vec[1] - p[1], lt.vec[2] - p[2])
    dc2 = dot(v, v)
    r2 = lt.size * lt.size
    if not dc2 > r2:
        return (0.0, 0.0, 1.0), 2.0, True
    dc = math.sqrt(dc2)
    s2 = r2 / dc2
    return (v[0] / dc, v[1] / dc, v[2] / dc), s2 / (1.0 + math.sqrt(1.0 - s2)), False


@njit(cache=True)
def sample_sphere_light(lt, p, u1, u2):
    """A direction from p towards sphere light lt. Returns (w, dist, pdf): the unit
    direction, the distance to the sphere along it and its density per steradian (0: no
    sample). Outside: uniform in the cone of the sphere (sample_cone), dist the near root
    d cos theta - sqrt(r^2 - d^2 sin^2 theta) with sin^2 theta = x (2 - x), x = 1 - cos theta
    from the sampler's own digits. Inside: a point q uniform on the surface."""
    axis, omc, inside = sphere_cone(lt, p)
    r = lt.size
    if not inside:
        w, pdf = sample_cone(u1, u2, axis, omc)
        v = (lt.vec[0] - p[0], lt.vec[1] - p[1], lt.vec[2] - p[2])
        dc2 = dot(v, v)
        x = u1 * omc
        dist = math.sqrt(dc2) * (1.0 - x) - math.sqrt(max(0.0, r * r - dc2 * x * (2.0 - x)))
        return w, dist, pdf
    n, _ = sample_uniform_sphere(u1, u2)
    v = (lt.vec[0] + r * n[0] - p[0], lt.vec[1] + r * n[1] - p[1], lt.vec[2] + r * n[2] - p[2])
    dist = math.sqrt(dot(v, v))
    if not dist > 0.0:
        return (0.0, 0.0, 1.0), 0.0, 0.0
    w = (v[0] / dist, v[1] / dist, v[2] / dist)
    c = abs(dot(n, w))
    if not c > 0.0:
        return w, dist, 0.0
    return w, dist, dist * dist * INV_4PI / (r * r * c)


@njit(cache=True)
def sphere_light_pdf(lt, p, w, t):
    """Density per steradian of ``sample_sphere_light`` from p at unit direction w, whose
    ray meets the sphere at distance t (sphere_hit)."""
    axis, omc, inside = sphere_cone(lt, p)
    if not inside:
        return cone_pdf(w, axis, omc)
    r = lt.size
    x = (p[0] + t * w[0] - lt.vec[0], p[1] + t * w[1] - lt.vec[1], p[2] + t * w[2] - lt.vec[2])
    c = abs(dot(x, w)) / r
    if not c > 0.0:
        return 0.0
    return t * t * INV_4PI / (r * r * c)


@njit(cache=True)
def sample_area_light(lt, p, u1, u2):
    """A direction from p towards area light lt (is_area_light). Returns (w, dist, pdf,
    radiance): the direction, the distance to the light (inf for a sun), its density per
    steradian (0: no sample) and the radiance along it per unit of lt.color."""
    if lt.type == LIGHT_DIRECTIONAL:
        w, pdf = sample_cone(u1, u2, (-lt.vec[0], -lt.vec[1], -lt.vec[2]), lt.size)
        return w, math.inf, pdf, sun_radiance(lt)
    w, dist, pdf = sample_sphere_light(lt, p, u1, u2)
    return w, dist, pdf, 1.0


@njit(cache=True)
def nearest_sphere(prm, lights, o, d):
    """(t, i): the first sphere light the ray o + t d meets, (inf, -1) if none."""
    t_best = math.inf
    best = -1
    for i in range(prm.n_lights):
        if lights[i].type != LIGHT_SPHERE:
            continue
        t = sphere_hit(lights[i], o, d)
        if t < t_best:
            t_best = t
            best = i
    return t_best, best
