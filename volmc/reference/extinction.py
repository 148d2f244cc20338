"""Extinction along a ray for the transmittance estimators: grids and analytic 1-D profiles.

An extinction source is a float64 array ``med`` (MED_SIZE entries) plus a grid array:

* ``med[0] = MED_GRID``: mu(t) = scale * trilinear density at o + t d;
  med[1:4] = bmin, med[4:7] = 1 / extent, med[7] = scale.
* ``med[0]`` = one of the 1-D profiles below: mu is a function of the ray parameter t alone
  (o, d and grid are ignored), with parameters a = med[1], b = med[2], c = med[3],
  s = med[4] and the segment length L = med[5]:

  =================  ==============================================  ===================
  kind               mu(t)                                           parameters
  =================  ==============================================  ===================
  MED_CONSTANT       a                                               a >= 0
  MED_RAMP           a + (b - a) t / L                               a, b >= 0
  MED_GAUSS_BUMP     a + b exp(-(t - c)^2 / (2 s^2))                 a, b >= 0
  MED_GAUSS_HOLE     a - b exp(-(t - c)^2 / (2 s^2))                 0 <= b <= a
  MED_COSINE         a (1 + b cos(2 pi c t / L + s))                 a >= 0, 0 <= b <= 1
  =================  ==============================================  ===================

Every call to ``extinction`` counts one density lookup in ``counters[C_LOOKUPS]``.
``optical_depth_profile`` gives the closed-form integral of a profile (ground truth).
"""

import math

import numpy as np
from numba import njit

from ..constants import (MED_CONSTANT, MED_COSINE, MED_GAUSS_BUMP, MED_GAUSS_HOLE, MED_GRID,
                         MED_RAMP, MED_SIZE)
from ..params import C_LOOKUPS, C_OVER_MAJORANT
from .grid import grid_lookup

PROFILE_NAMES = {MED_CONSTANT: "constant", MED_RAMP: "linear ramp",
                 MED_GAUSS_BUMP: "Gaussian bump", MED_GAUSS_HOLE: "Gaussian hole",
                 MED_COSINE: "cosine"}


@njit(cache=True, inline="always")
def _profile(med, t):
    kind = int(med[0])
    a, b, c, s, L = med[1], med[2], med[3], med[4], med[5]
    if kind == MED_CONSTANT:
        return a
    if kind == MED_RAMP:
        return a + (b - a) * t / L
    if kind == MED_GAUSS_BUMP:
        x = (t - c) / s
        return a + b * math.exp(-0.5 * x * x)
    if kind == MED_GAUSS_HOLE:
        x = (t - c) / s
        return max(a - b * math.exp(-0.5 * x * x), 0.0)
    return a * (1.0 + b * math.cos(2.0 * math.pi * c * t / L + s))


@njit(cache=True, inline="always")
def extinction(med, grid, o, d, t, counters):
    """mu at ray parameter t (1/world unit); counts one lookup."""
    counters[C_LOOKUPS] += 1
    if int(med[0]) == MED_GRID:
        p = (o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2])
        return med[7] * grid_lookup(grid, (med[1], med[2], med[3]), (med[4], med[5], med[6]), p)
    return _profile(med, t)


@njit(cache=True, inline="always")
def lookup(med, grid, o, d, t, counters, mbar):
    """extinction() that also counts lookups above the majorant mbar (a broken bound is
    counted, never silent)."""
    mu = extinction(med, grid, o, d, t, counters)
    if mu > mbar:
        counters[C_OVER_MAJORANT] += 1
    return mu


def optical_depth_profile(med, t0, t1):
    """Closed-form integral of a 1-D profile over [t0, t1] (float64)."""
    kind = int(med[0])
    a, b, c, s, L = (float(x) for x in med[1:6])
    if kind == MED_CONSTANT:
        return a * (t1 - t0)
    if kind == MED_RAMP:
        def F(t):
            return a * t + 0.5 * (b - a) * t * t / L
        return F(t1) - F(t0)
    if kind in (MED_GAUSS_BUMP, MED_GAUSS_HOLE):
        sign = 1.0 if kind == MED_GAUSS_BUMP else -1.0
        g = s * math.sqrt(0.5 * math.pi) * (math.erf((t1 - c) / (s * math.sqrt(2.0)))
                                            - math.erf((t0 - c) / (s * math.sqrt(2.0))))
        return a * (t1 - t0) + sign * b * g
    if kind == MED_COSINE:
        k = 2.0 * math.pi * c / L
        return a * (t1 - t0) + a * b / k * (math.sin(k * t1 + s) - math.sin(k * t0 + s))
    raise ValueError(f"not a 1-D profile: kind {kind}")


def profile_bounds(med, t0, t1, n=20001):
    """(minimum, maximum, mean) of a 1-D profile over [t0, t1] (dense sampling plus the
    analytic extremes; the maximum is a true majorant, the minimum a true minorant)."""
    ts = np.linspace(t0, t1, n)
    vals = np.array([_profile(med, t) for t in ts])
    kind = int(med[0])
    a, b, c = float(med[1]), float(med[2]), float(med[3])
    lo, hi = float(vals.min()), float(vals.max())
    if kind == MED_GAUSS_BUMP and t0 <= c <= t1:
        hi = max(hi, a + b)
    if kind == MED_GAUSS_HOLE and t0 <= c <= t1:
        lo = min(lo, max(a - b, 0.0))
    if kind == MED_COSINE:  # the analytic extremes bound every sub-interval
        hi, lo = a * (1 + b), a * (1 - b)
    mean = optical_depth_profile(med, t0, t1) / (t1 - t0)
    return lo, hi, mean


def make_profile(kind, a, b=0.0, c=0.0, s=1.0, L=1.0):
    """``med`` array of a 1-D profile."""
    med = np.zeros(MED_SIZE)
    med[:6] = [kind, a, b, c, s, L]
    return med


def make_grid_medium(bmin, bmax, scale):
    """``med`` array of a grid medium."""
    med = np.zeros(MED_SIZE)
    med[0] = MED_GRID
    med[1:4] = bmin
    med[4:7] = [1.0 / (hi - lo) for lo, hi in zip(bmin, bmax)]
    med[7] = scale
    return med
