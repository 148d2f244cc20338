"""Sampling warps: pure functions of explicit uniforms returning (sample, pdf).

Conventions (shared with ``kernels/sampling.h``):

* Directions are 3-tuples of floats; they are unit vectors unless a docstring says otherwise.
* Every warp ``sample_X(u...)`` has a density twin ``X_pdf(...)`` with the same measure:
  distances in 1 / world unit, directions per steradian, points of the unit disc per unit
  area.
* Uniforms are in [0, 1) (see ``rng.py``: never 1.0), so logarithms of ``1 - u`` are finite.
"""

import math

from numba import njit

from ..constants import (EQUIANGULAR_MIN_WIDTH, INV_4PI, INV_PI, MIS_POWER, PI_OVER_2,
                         PI_OVER_4, TWO_PI)


@njit(cache=True, inline="always")
def sample_exponential(u, a):
    """Distance t >= 0 from the density a e^{-a t} (a in 1/world unit), by inversion.

    Returns (t, pdf). For a <= 0 there is no collision: (inf, 0).
    """
    if a <= 0.0:
        return math.inf, 0.0
    t = -math.log1p(-u) / a
    return t, a * (1.0 - u)   # a e^{-a t} at the sampled t: e^{-a t} = 1 - u, no exp needed


@njit(cache=True, inline="always")
def exponential_pdf(t, a):
    """Density a e^{-a t} of ``sample_exponential`` at distance t."""
    if a <= 0.0 or t < 0.0:
        return 0.0
    return a * math.exp(-a * t)


@njit(cache=True, inline="always")
def invert_exponential_sample(t, a):
    """The uniform u that ``sample_exponential(u, a)`` maps to distance t:
    u = 1 - e^{-a t}, written -expm1(-a t) so that small a t keeps its digits."""
    return -math.expm1(-a * t)


@njit(cache=True, inline="always")
def sample_uniform_sphere(u1, u2):
    """Uniform direction on the unit sphere: z = 1 - 2 u1, phi = 2 pi u2. Returns (w, pdf)."""
    z = 1.0 - 2.0 * u1
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = TWO_PI * u2
    return (r * math.cos(phi), r * math.sin(phi), z), INV_4PI


@njit(cache=True, inline="always")
def uniform_sphere_pdf():
    """Density of ``sample_uniform_sphere``: 1 / (4 pi) per steradian."""
    return INV_4PI


@njit(cache=True, inline="always")
def invert_uniform_sphere(w):
    """(u1, u2) that ``sample_uniform_sphere`` maps to unit direction w: u1 = (1 - z) / 2,
    u2 = phi / (2 pi) with phi = atan2(y, x) in [0, 2 pi). At the poles phi is arbitrary."""
    phi = math.atan2(w[1], w[0])
    if phi < 0.0:
        phi += TWO_PI
    return 0.5 * (1.0 - w[2]), phi / TWO_PI


@njit(cache=True, inline="always")
def sample_uniform_disc(u1, u2):
    """Uniform point (x, y) on the unit disc by Shirley and Chiu's concentric mapping (1997):
    the square [-1, 1]^2 goes to the disc ring by ring, |a| > |b| to the wedge about the x
    axis and the rest to the wedge about y, so strata stay compact and nearly square and
    low-discrepancy points stay well spread (a polar r = sqrt(u1) mapping squeezes them).
    Returns ((x, y), pdf), pdf 1 / pi per unit area."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    if abs(a) > abs(b):
        r = a
        phi = PI_OVER_4 * (b / a)
    else:
        r = b
        phi = PI_OVER_2 - PI_OVER_4 * (a / b if b != 0.0 else 0.0)
    return (r * math.cos(phi), r * math.sin(phi)), INV_PI


@njit(cache=True, inline="always")
def uniform_disc_pdf():
    """Density of ``sample_uniform_disc``: 1 / pi per unit area of the unit disc."""
    return INV_PI


@njit(cache=True, inline="always")
def invert_uniform_disc(p):
    """(u1, u2) that ``sample_uniform_disc`` maps to the point p of the unit disc.

    Wedge |x| > |y| came from |a| > |b|: there a = r sign(x) and b / a = atan(y / x) / (pi/4)
    (the wedge's angle to its axis, whichever side of the origin); otherwise b = r sign(y)
    and a / b = atan(x / y) / (pi/4). The origin gives (1/2, 1/2)."""
    x, y = p[0], p[1]
    r = math.sqrt(x * x + y * y)
    if r == 0.0:
        return 0.5, 0.5
    if abs(x) > abs(y):
        a = math.copysign(r, x)
        b = a * math.atan(y / x) / PI_OVER_4
    else:
        b = math.copysign(r, y)
        a = b * math.atan(x / y) / PI_OVER_4
    return 0.5 * (a + 1.0), 0.5 * (b + 1.0)


@njit(cache=True, inline="always")
def coordinate_system(n):
    """Two unit vectors (s, t) completing unit vector n to a right-handed orthonormal frame.

    Branch-free construction of Duff et al. 2017 ("Building an orthonormal basis,
    revisited"): continuous except at n.z = -0, and exact for n = +-z.
    """
    sign = math.copysign(1.0, n[2])
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    s = (1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])
    t = (b, sign + n[1] * n[1] * a, -n[1])
    return s, t


@njit(cache=True, inline="always")
def from_frame(n, cos_theta, sin_theta, phi):
    """Direction with polar angle theta about unit n and azimuth phi in n's frame."""
    s, t = coordinate_system(n)
    cp = math.cos(phi) * sin_theta
    sp = math.sin(phi) * sin_theta
    return (cp * s[0] + sp * t[0] + cos_theta * n[0],
            cp * s[1] + sp * t[1] + cos_theta * n[1],
            cp * s[2] + sp * t[2] + cos_theta * n[2])


@njit(cache=True, inline="always")
def sample_cone(u1, u2, axis, omc):
    """Uniform direction in the cone about unit ``axis`` whose half-angle theta_max is
    given as omc = 1 - cos theta_max in (0, 2] (apart from cos, so that a narrow cone -- the
    sun's is 4e-5 -- keeps its digits): 1 - cos theta = u1 omc, phi = 2 pi u2 in the frame
    of coordinate_system(axis). Returns (w, pdf), pdf 1 / (2 pi omc) per steradian."""
    x = u1 * omc
    sin_t = math.sqrt(max(0.0, x * (2.0 - x)))
    return from_frame(axis, 1.0 - x, sin_t, TWO_PI * u2), 1.0 / (TWO_PI * omc)


@njit(cache=True, inline="always")
def cone_pdf(w, axis, omc):
    """Density of ``sample_cone`` at unit w: 1 / (2 pi omc) inside the cone, else 0. The
    test is 1 - cos theta = |w - axis|^2 / 2 <= omc, which keeps its digits near the axis
    where 1 - dot(w, axis) would cancel."""
    v = (w[0] - axis[0], w[1] - axis[1], w[2] - axis[2])
    if 0.5 * dot(v, v) > omc:
        return 0.0
    return 1.0 / (TWO_PI * omc)


@njit(cache=True, inline="always")
def invert_cone(w, axis, omc):
    """(u1, u2) that ``sample_cone(u1, u2, axis, omc)`` maps to unit w in the cone."""
    v = (w[0] - axis[0], w[1] - axis[1], w[2] - axis[2])
    s, t = coordinate_system(axis)
    phi = math.atan2(dot(w, t), dot(w, s))
    if phi < 0.0:
        phi += TWO_PI
    return 0.5 * dot(v, v) / omc, phi / TWO_PI


@njit(cache=True, inline="always")
def dot(a, b):
    """Dot product of two 3-tuples."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, inline="always")
def normalize(a):
    """a / |a| for a non-zero 3-tuple."""
    inv = 1.0 / math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    return (a[0] * inv, a[1] * inv, a[2] * inv)


@njit(cache=True, inline="always")
def mis_balance(pdf_a, pdf_b):
    """Balance-heuristic weight of strategy a against strategy b, one sample each:
    pdf_a / (pdf_a + pdf_b) (Veach 1997). Both pdfs in the same measure (1/sr here)."""
    return pdf_a / (pdf_a + pdf_b)


@njit(cache=True, inline="always")
def mis_power(pdf_a, pdf_b):
    """Power-heuristic weight (exponent 2) of strategy a against strategy b, one sample each:
    pdf_a^2 / (pdf_a^2 + pdf_b^2) (Veach 1997). The two weights of a pair sum to 1, so the
    combination stays unbiased; it leans harder on the strategy with the larger pdf."""
    a = pdf_a * pdf_a
    return a / (a + pdf_b * pdf_b)


@njit(cache=True, inline="always")
def mis_weight(kind, pdf_a, pdf_b):
    """Weight of strategy a against b by the heuristic ``kind`` (MIS_BALANCE, MIS_POWER)."""
    if kind == MIS_POWER:
        return mis_power(pdf_a, pdf_b)
    return mis_balance(pdf_a, pdf_b)


@njit(cache=True, inline="always")
def mis_weight_over(kind, pdf_a, pdf_b):
    """``mis_weight(kind, pdf_a, pdf_b) / pdf_a`` without dividing by pdf_a: finite where
    pdf_a is tiny or 0 beside pdf_b (an emitter sample next to its vertex in a dense
    emitter, whose densities in 1/sr are ~1/dist^2: the estimator's f w / pdf_a then needs
    no 1/dist^2 at all). pdf_a, pdf_b >= 0, not both 0."""
    if kind != MIS_POWER:
        return 1.0 / (pdf_a + pdf_b)
    m = max(pdf_a, pdf_b)
    a, b = pdf_a / m, pdf_b / m
    return a / ((a * a + b * b) * m)


@njit(cache=True, inline="always")
def equiangular_side(h, ta, tb):
    """Where the foot h lies against the interval [ta, tb]: 1 before it (ta >= h), -1
    after it (tb <= h), 0 inside. It chooses the angle equiangular sampling measures
    (``equiangular_angle``)."""
    if ta - h >= 0.0:
        return 1
    if tb - h <= 0.0:
        return -1
    return 0


@njit(cache=True, inline="always")
def equiangular_angle(t, h, D, side):
    """The angle of the point at ray parameter t as equiangular sampling measures it.

    Side 0 (the foot inside the interval): theta = atan2(t - h, D), from the foot, which
    is accurate there. On one side of the foot, theta tends to +-pi/2 where the point lies
    near the ray's line, and its float keeps too few digits of the difference: a point
    light at the camera's pinhole left a path's interval a few ulps wide, so the samples
    fell on a few angles the pdf did not describe (+21 % in float32, +1.8 % in float64).
    There the angle is measured from the ray instead, phi = atan2(D, side (t - h)) =
    pi/2 - |theta|, which keeps its relative precision as D -> 0."""
    x = t - h
    if side == 0:
        return math.atan2(x, D)
    return math.atan2(D, side * x)


@njit(cache=True, inline="always")
def equiangular_uniform(a, b):
    """Whether the interval of angles a, b is too narrow for its floats (at most
    EQUIANGULAR_MIN_WIDTH of their size): sampled uniformly instead, as equal angles."""
    return not abs(b - a) > EQUIANGULAR_MIN_WIDTH * max(abs(a), abs(b))


@njit(cache=True, inline="always")
def sample_equiangular(u, h, D, ta, tb):
    """Distance t in [ta, tb] along a ray, from the equiangular density towards a point
    (Kulla & Fajardo 2012): t = h + D tan(theta), theta uniform between the angles under
    which the point sees ta and tb (measured as ``equiangular_angle`` says, which is the
    same map).

    h: ray parameter of the point's foot on the ray (world units); D > 0: the point's
    distance from the ray's line; ta < tb: the interval (world units). The density is
    D / (|theta_b - theta_a| (D^2 + (t - h)^2)) per world unit, proportional to 1 / r^2,
    the falloff of a point light. Returns (t, pdf); t is clamped into [ta, tb] (rounding
    in tan can overshoot by an ulp).

    An interval whose angles are too close for their floats to sample between
    (``equiangular_uniform``: a path segment of 1e-7 units seen from the light, in float32)
    is sampled uniformly instead, pdf 1 / (tb - ta): the equiangular density is uniform to
    within that width there, and samples drawn between a handful of representable angles
    would follow a trapezoidal rule, not the pdf. ``equiangular_pdf`` and the inverse make
    the same switch. An empty interval gives pdf 0."""
    side = equiangular_side(h, ta, tb)
    a = equiangular_angle(ta, h, D, side)
    b = equiangular_angle(tb, h, D, side)
    if equiangular_uniform(a, b):
        if not tb > ta:
            return ta, 0.0
        return ta + u * (tb - ta), 1.0 / (tb - ta)
    th = a + u * (b - a)
    if side == 0:
        t = h + D * math.tan(th)
    else:
        t = h + side * (D / math.tan(th))
    t = min(max(t, ta), tb)
    x = t - h
    return t, D / (abs(b - a) * (D * D + x * x))


@njit(cache=True, inline="always")
def equiangular_pdf(t, h, D, ta, tb):
    """Density of ``sample_equiangular`` at t (per world unit); 0 outside [ta, tb]."""
    if t < ta or t > tb or not tb > ta:
        return 0.0
    side = equiangular_side(h, ta, tb)
    a = equiangular_angle(ta, h, D, side)
    b = equiangular_angle(tb, h, D, side)
    if equiangular_uniform(a, b):
        return 1.0 / (tb - ta)
    x = t - h
    return D / (abs(b - a) * (D * D + x * x))


@njit(cache=True, inline="always")
def invert_equiangular_sample(t, h, D, ta, tb):
    """The uniform u that ``sample_equiangular(u, h, D, ta, tb)`` maps to t."""
    side = equiangular_side(h, ta, tb)
    a = equiangular_angle(ta, h, D, side)
    b = equiangular_angle(tb, h, D, side)
    if equiangular_uniform(a, b):
        return (t - ta) / (tb - ta)
    return (equiangular_angle(t, h, D, side) - a) / (b - a)
