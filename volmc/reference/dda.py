"""3-D DDA over a majorant grid: the ray segment [t0, t1] cut at cell faces.

``dda_init`` sets up a walk and ``dda_next`` yields one segment per call, in order:
(t_enter, t_exit, iz, iy, ix), until it returns ok = False. Segments tile [t0, t1] without
gaps or overlaps (t_exit of one is t_enter of the next), so an estimator can integrate a
piecewise-constant majorant exactly. Robustness (robustness case 6):

* a zero direction component (+0.0 or -0.0) never crosses that axis (its next crossing is
  +inf), so axis-parallel rays need no special case and no 0 * inf appears;
* the starting cell is found from the point at t0 and clamped into the grid, so rays that
  start on a box face, a cell face or inside the box start in a valid cell;
* each step moves to a neighbouring cell along one axis, so a walk takes at most
  cx + cy + cz steps and always ends; a segment can have zero length when the ray runs
  exactly along a cell face or starts on one (callers skip those at no cost).

State layout (float64 array of DDA_STATE_SIZE): [t, t1, tnext_x, tnext_y, tnext_z,
dt_x, dt_y, dt_z, ix, iy, iz, step_x, step_y, step_z, cx, cy, cz, done].
"""

import math

import numpy as np
from numba import njit

DDA_STATE_SIZE = 18


@njit(cache=True)
def dda_init(state, o, d, t0, t1, bmin, bmax, res_zyx):
    """Start a walk of ray o + t d over [t0, t1] through a (cz, cy, cx) grid of cells that
    tiles the box [bmin, bmax]. The segment must already be clipped to the box."""
    cz, cy, cx = res_zyx
    n = (cx, cy, cz)
    state[0] = t0
    state[1] = t1
    state[17] = 1.0 if not t1 > t0 else 0.0
    for a in range(3):
        size = (bmax[a] - bmin[a]) / n[a]
        p = o[a] + t0 * d[a]
        i = int(math.floor((p - bmin[a]) / size))
        i = min(max(i, 0), n[a] - 1)
        state[8 + a] = i
        state[14 + a] = n[a]
        if d[a] > 0.0:
            state[11 + a] = 1.0
            state[2 + a] = (bmin[a] + (i + 1) * size - o[a]) / d[a]
            state[5 + a] = size / d[a]
        elif d[a] < 0.0:
            state[11 + a] = -1.0
            state[2 + a] = (bmin[a] + i * size - o[a]) / d[a]
            state[5 + a] = -size / d[a]
        else:
            state[11 + a] = 0.0
            state[2 + a] = math.inf
            state[5 + a] = math.inf


@njit(cache=True)
def dda_next(state):
    """Next segment: (ok, t_enter, t_exit, iz, iy, ix). ok is False once the walk is over."""
    if state[17] != 0.0:
        return False, 0.0, 0.0, 0, 0, 0
    a = 0
    if state[3] < state[2 + a]:
        a = 1
    if state[4] < state[2 + a]:
        a = 2
    t_enter = state[0]
    t_exit = min(max(state[2 + a], t_enter), state[1])
    ix, iy, iz = int(state[8]), int(state[9]), int(state[10])
    if t_exit >= state[1]:
        state[17] = 1.0
    else:
        i = int(state[8 + a] + state[11 + a])
        if i < 0 or i >= int(state[14 + a]):
            state[17] = 1.0
            t_exit = state[1]   # rounding left the grid early: the last cell ends the segment
        else:
            state[8 + a] = i
            state[2 + a] += state[5 + a]
    state[0] = t_exit
    return True, t_enter, t_exit, iz, iy, ix


@njit(cache=True)
def dda_segments(o, d, t0, t1, bmin, bmax, res_zyx, out):
    """Fill out[k] = (t_enter, t_exit, iz, iy, ix) for the whole walk; returns the count."""
    state = np.empty(DDA_STATE_SIZE)
    dda_init(state, o, d, t0, t1, bmin, bmax, res_zyx)
    k = 0
    while True:
        ok, ta, tb, iz, iy, ix = dda_next(state)
        if not ok or k >= out.shape[0]:
            break
        out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4] = ta, tb, iz, iy, ix
        k += 1
    return k
