"""Environment maps: radiance from a lat-long image, and the sampler that picks directions in
proportion to it (twin of ``kernels/environment.h``).

Conventions (Mitsuba 3's ``envmap``, so its peer maps a file one to one):

* The map's frame has y up. Texture coordinates u = phi / (2 pi) (columns, left to right) and
  v = theta / pi (rows, row 0 at the top, which is +y), and the direction of (u, v) is
  (sin phi sin theta, cos theta, -cos phi sin theta).
* ``prm.env_rot`` (3x3, row-major) takes a scene direction into the map's frame: the transpose
  of the light's ``rotation``, which turns the map in the scene (world = rotation x map).
  The scene frame of the kernels (pack.scene_frame) only moves and scales, so directions in
  it are world directions.
* Radiance is the texel holding (u, v) times ``prm.env`` (the light's radiance x strength):
  nearest texel, piecewise constant, which is exactly the density the sampler draws from.
* ``EnvMap`` arrays (``environment_distribution`` builds them): texels [H, W, 3]; pdf [H, W],
  the density in (u, v) of each texel (the unit square has area 1); marginal [H + 1], the
  CDF over rows; conditional [H, W + 1], each row's CDF over its columns.
* Sampling is the inversion method on that piecewise-constant 2-D density: u1 picks a row by
  the marginal CDF, u2 a column by the row's CDF, each remapped within its texel. Its density
  per steradian is pdf_uv / (2 pi^2 sin theta), since d(omega) = 2 pi^2 sin theta du dv.
* Near the poles, angles are taken from the nearer pole and theta from atan2, not acos(y):
  within 2.4e-4 rad of a pole a float32 y rounds to +-1, so the kernels' acos gave theta 0
  or pi there, and a pdf of 0 (or several times off) at directions the sampler returns with
  its true pdf. MIS then counted the light of a map's top and bottom rows twice (+5.5 % on
  a zenith sun in a 4096 x 2048 map). The float64 reference computes the same way.
"""

import math
from collections import namedtuple

import numpy as np
from numba import njit

from ..constants import PI, TWO_PI

#: An environment map as the renderers take it (module docstring); ``no_env`` is the
#: placeholder of a scene without one.
EnvMap = namedtuple("EnvMap", ["texels", "pdf", "marginal", "conditional"])

#: Luminance weights of linear Rec. 709 RGB (the weights of the sampling density).
LUMINANCE = (0.2126, 0.7152, 0.0722)


def no_env(real=np.float64):
    """The placeholder EnvMap of a scene without an environment map (1 x 1, never read)."""
    return EnvMap(np.zeros((1, 1, 3), real), np.ones((1, 1), real), np.array([0.0, 1.0], real),
                  np.array([[0.0, 1.0]], real))


def environment_distribution(texels, compensate=False, real=np.float64):
    """The EnvMap of float RGB ``texels`` [H, W, 3] (finite, >= 0): a density over texels in
    proportion to luminance x sin(theta at the row's centre). With ``compensate`` the
    luminance first loses its mean and is clamped at 0 (Karlik et al. 2019, "MIS
    compensation"): the directions phase sampling already finds well get none of it, which
    pays when MIS combines the two. Where nothing is left (a black map, or a constant one
    compensated) the density falls back to sin(theta) alone, uniform over the sphere. Sums
    are formed in float64; the arrays are returned in ``real``."""
    t = np.asarray(texels, np.float64)
    h, w = t.shape[:2]
    d = t[..., 0] * LUMINANCE[0] + t[..., 1] * LUMINANCE[1] + t[..., 2] * LUMINANCE[2]
    if compensate:
        d = np.maximum(d - d.mean(), 0.0)
    sin_row = np.sin(PI * (np.arange(h) + 0.5) / h)
    wt = d * sin_row[:, None]
    if not wt.sum() > 0.0:
        wt = np.broadcast_to(sin_row[:, None], (h, w)).copy()
    row = wt.sum(axis=1)
    total = row.sum()
    marginal = np.concatenate([[0.0], np.cumsum(row) / total])
    marginal[-1] = 1.0
    # Each row's CDF over its columns; a row of weight 0 (never picked) a uniform one.
    some = row > 0.0
    conditional = np.empty((h, w + 1))
    conditional[:, 0] = 0.0
    conditional[:, 1:] = np.where(some[:, None],
                                  np.cumsum(wt, axis=1) / np.where(some, row, 1.0)[:, None],
                                  np.arange(1, w + 1) / w)
    conditional[:, -1] = 1.0
    pdf = wt / total * (h * w)
    return EnvMap(np.ascontiguousarray(t, real), np.ascontiguousarray(pdf, real),
                  np.ascontiguousarray(marginal, real), np.ascontiguousarray(conditional, real))


@njit(cache=True)
def env_direction(u, v):
    """The map-frame direction of texture coordinates (u, v); theta from the nearer pole."""
    phi = TWO_PI * u
    theta = PI * min(v, 1.0 - v)
    s = math.sin(theta)
    c = math.cos(theta)
    return (math.sin(phi) * s, -c if v > 0.5 else c, -math.cos(phi) * s)


@njit(cache=True)
def env_sin_theta(v):
    """sin(pi v) for v in [0, 1], from the nearer pole."""
    return math.sin(PI * min(v, 1.0 - v))


@njit(cache=True)
def env_uv_sin(w):
    """(u, v, sin theta): texture coordinates in [0, 1] of map-frame unit direction w
    (inverse of env_direction; at the poles u is 0), and the sine of its polar angle."""
    phi = math.atan2(w[0], -w[2])
    if phi < 0.0:
        phi += TWO_PI
    s = math.sqrt(w[0] * w[0] + w[2] * w[2])
    return phi / TWO_PI, math.atan2(s, w[1]) / PI, s


@njit(cache=True)
def env_uv(w):
    """Texture coordinates (u, v) of map-frame unit direction w (env_uv_sin)."""
    u, v, _ = env_uv_sin(w)
    return u, v


@njit(cache=True)
def env_to_map(prm, w):
    """Scene direction w in the map's frame (prm.env_rot)."""
    r = prm.env_rot
    return (r[0] * w[0] + r[1] * w[1] + r[2] * w[2], r[3] * w[0] + r[4] * w[1] + r[5] * w[2],
            r[6] * w[0] + r[7] * w[1] + r[8] * w[2])


@njit(cache=True)
def env_from_map(prm, m):
    """Map-frame direction m in the scene (the transpose of prm.env_rot)."""
    r = prm.env_rot
    return (r[0] * m[0] + r[3] * m[1] + r[6] * m[2], r[1] * m[0] + r[4] * m[1] + r[7] * m[2],
            r[2] * m[0] + r[5] * m[1] + r[8] * m[2])


@njit(cache=True)
def env_texel(env, u, v):
    """(row, column) of the texel holding (u, v); coordinates at 1 go to the last (clamped on
    both sides, as the kernels' lanes need)."""
    h, w = env.pdf.shape
    return max(0, min(int(v * h), h - 1)), max(0, min(int(u * w), w - 1))


@njit(cache=True)
def env_radiance(prm, env, w):
    """Radiance arriving from scene direction w (unit), RGB: the map's texel times prm.env."""
    u, v = env_uv(env_to_map(prm, w))
    r, c = env_texel(env, u, v)
    t = env.texels[r, c]
    return (prm.env[0] * t[0], prm.env[1] * t[1], prm.env[2] * t[2])


@njit(cache=True)
def cdf_find(cdf, x):
    """The largest i in [0, len(cdf) - 2] with cdf[i] <= x, by bisection: for a CDF that
    starts at 0 and ends at 1 and x in [0, 1), the interval [cdf[i], cdf[i + 1]) holding x,
    never an empty one."""
    lo = 0
    hi = len(cdf) - 1
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        if cdf[mid] <= x:
            lo = mid
        else:
            hi = mid
    return lo


@njit(cache=True)
def sample_environment(prm, env, u1, u2):
    """A scene direction from the map's density (module docstring). Returns (w, pdf), pdf
    per steradian (0 where sin theta is 0, a set of measure zero)."""
    h, w = env.pdf.shape
    r = cdf_find(env.marginal, u1)
    a, b = env.marginal[r], env.marginal[r + 1]
    v = (r + min((u1 - a) / (b - a), 1.0)) / h
    row = env.conditional[r]
    c = cdf_find(row, u2)
    a, b = row[c], row[c + 1]
    u = (c + min((u2 - a) / (b - a), 1.0)) / w
    m = env_direction(u, v)
    s = env_sin_theta(v)
    pdf = env.pdf[r, c] / (2.0 * PI * PI * s) if s > 0.0 else 0.0
    return env_from_map(prm, m), pdf


@njit(cache=True)
def environment_pdf(prm, env, w):
    """Density per steradian of ``sample_environment`` at scene direction w (unit)."""
    u, v, s = env_uv_sin(env_to_map(prm, w))
    r, c = env_texel(env, u, v)
    return env.pdf[r, c] / (2.0 * PI * PI * s) if s > 0.0 else 0.0


@njit(cache=True)
def invert_environment(prm, env, w):
    """(u1, u2) that ``sample_environment`` maps to scene direction w (unit)."""
    h, wd = env.pdf.shape
    u, v = env_uv(env_to_map(prm, w))
    r, c = env_texel(env, u, v)
    a, b = env.marginal[r], env.marginal[r + 1]
    u1 = a + (v * h - r) * (b - a)
    row = env.conditional[r]
    a, b = row[c], row[c + 1]
    return u1, a + (u * wd - c) * (b - a)
