"""Exact optical depth along a ray through a trilinear grid (ground truth, float64).

Along a straight ray the clamp-to-edge trilinear density is, on each axis, linear in t
between successive crossings of voxel-centre planes (and constant in the half-voxel clamp
zone next to a face), so between consecutive crossings of any axis it is a polynomial of
degree <= 3 in t. Gauss-Legendre quadrature with 3 nodes is exact for degree 5, so summing
it over the pieces gives the optical depth up to float64 rounding.
"""

import math

import numpy as np
from numba import njit

from .grid import grid_lookup

# 3-point Gauss-Legendre nodes and weights on [-1, 1].
_GL_X = (-math.sqrt(3.0 / 5.0), 0.0, math.sqrt(3.0 / 5.0))
_GL_W = (5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0)


@njit(cache=True)
def _breakpoints(o, d, bmin, bmax, shape_xyz, t0, t1):
    """Sorted ray parameters in [t0, t1] where the ray crosses a voxel-centre plane."""
    pts = [t0, t1]
    for a in range(3):
        if d[a] == 0.0:
            continue
        n = shape_xyz[a]
        h = (bmax[a] - bmin[a]) / n
        for i in range(n):
            c = bmin[a] + (i + 0.5) * h
            t = (c - o[a]) / d[a]
            if t0 < t < t1:
                pts.append(t)
    arr = np.array(pts)
    arr.sort()
    return arr


@njit(cache=True)
def optical_depth_exact(grid, bmin, bmax, scale, o, d, t0, t1):
    """Integral of scale * density(o + t d) dt over [t0, t1] (world units; d need not be unit
    length, t is in units of |d|). The segment must lie inside the box."""
    if t1 <= t0:
        return 0.0
    nz, ny, nx = grid.shape
    inv_ext = (1.0 / (bmax[0] - bmin[0]), 1.0 / (bmax[1] - bmin[1]), 1.0 / (bmax[2] - bmin[2]))
    ts = _breakpoints(o, d, bmin, bmax, (nx, ny, nz), t0, t1)
    total = 0.0
    for k in range(ts.size - 1):
        a = ts[k]
        b = ts[k + 1]
        if b <= a:
            continue
        half = 0.5 * (b - a)
        mid = 0.5 * (a + b)
        s = 0.0
        for j in range(3):
            t = mid + half * _GL_X[j]
            p = (o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2])
            s += _GL_W[j] * grid_lookup(grid, bmin, inv_ext, p)
        total += s * half
    norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    return scale * total * norm
