"""Emission sampling's distribution (render.emission_sampling; docs/emission_sampling.md):
where next-event estimation looks for emitted light inside the media.

Each emitting medium's box is cut into cells, one per VOXELS_PER_EMITTER_CELL voxels of its
finest field (density or emission) along each axis, at most EMITTER_MAX_CELLS. A cell's
weight approximates the power it emits, the integral of luminance(sigma_a Le) over it,

    luminance(sigma_a Le) = sum_c Y_c (1 - albedo_c) chroma_c mu(x) Le_c(x),

as the mean over a lattice of points inside the cell (a point per voxel, at least two per
cell and axis) of the fields the renderer interpolates; with bricks or a 1-D profile the
density factor is the cell's density bound. Plus SUPPORT_SHARE of the probability in
proportion to an upper bound of the same product over the cell (the majorant grid's
construction for each field, a blackbody's radiance through the table's running maximum),
so every cell where sigma_a Le can be positive has positive probability and light sampling
alone stays unbiased. The mean matters: a blackbody's radiance grows steeply with
temperature, so the bound alone is hundreds of times the power on a flame (a 48^3-cell
distribution of the plume in a cloud: 20x at 2 voxels per cell, 450x at 8), and the sampled
points would mostly fall where the flame is dim.

A medium is picked with probability proportional to its cells' weights times their volume
in the scene frame, a cell by an alias table (Walker 1977; Vose's construction), and a point
uniformly inside the cell.

The cells travel in the medium's ``table`` array, after the blackbody rows: row
``emitter_row + c`` holds (alias threshold, alias cell, probability) of cell
c = ix + cx (iy + cy iz). The record's ``emitter_density`` is this medium's probability times
|det| of its scene-to-medium map over a cell's volume in its own space: a cell of probability
P has density emitter_density x P per unit volume of the scene frame (reference/emitters.py).
"""

import numpy as np
from numba import njit

from .constants import (BLACKBODY_TABLE_SIZE, DENSITY_BRICKS, DENSITY_CONSTANT, DENSITY_GRID,
                        EMISSION_NONE, EMISSION_RADIANCE, EMITTER_MAX_CELLS)

#: Rec. 709 luminance of linear sRGB (R, G, B).
LUMINANCE_RGB = (0.2126, 0.7152, 0.0722)
#: Voxels per cell and axis of the finest field (at most EMITTER_MAX_CELLS cells per axis).
VOXELS_PER_EMITTER_CELL = 2
#: Points per axis at most of the lattice the cells' means are taken over.
MAX_LATTICE = 160
#: The share of the probability the cells' upper bounds carry (module docstring).
SUPPORT_SHARE = 0.01


@njit(cache=True)
def _push(i, scaled, small, large, ns, nl):
    """Cell i onto the stack of cells below (small) or at least (large) the mean weight;
    returns the stacks' new sizes."""
    if scaled[i] < 1.0:
        small[ns] = i
        return ns + 1, nl
    large[nl] = i
    return ns, nl + 1


@njit(cache=True)
def alias_table(w):
    """(threshold, alias) of Walker's alias method for weights w (1-D, float64, not all 0),
    by Vose's construction: cell i is kept when n u1 falls in i and u2 < threshold[i], else
    alias[i] is taken; every cell is then chosen with probability w_i / sum(w)."""
    n = w.size
    scaled = w * (n / w.sum())
    threshold = np.ones(n)
    alias = np.arange(n)
    small = np.empty(n, np.int64)
    large = np.empty(n, np.int64)
    ns = 0
    nl = 0
    for i in range(n):
        ns, nl = _push(i, scaled, small, large, ns, nl)
    while ns > 0 and nl > 0:
        ns -= 1
        nl -= 1
        s = small[ns]
        g = large[nl]
        threshold[s] = scaled[s]
        alias[s] = g
        scaled[g] -= 1.0 - scaled[s]
        ns, nl = _push(g, scaled, small, large, ns, nl)
    # What is left holds 1 up to rounding: kept with probability 1.
    return threshold, alias


def _resolution(dims_zyx):
    """Cells per axis: one per VOXELS_PER_EMITTER_CELL voxels, at most EMITTER_MAX_CELLS."""
    return tuple(min(EMITTER_MAX_CELLS, max(1, -(-int(n) // VOXELS_PER_EMITTER_CELL)))
                 for n in dims_zyx)


def _axis_weights(n_voxels, coords):
    """(i0, i1, f) of the trilinear lookup's convention (reference/grid.py) along one axis
    at normalised coordinates coords in [0, 1]."""
    x = np.clip(coords * n_voxels - 0.5, 0.0, n_voxels - 1.0)
    i0 = np.minimum(x.astype(np.int64), n_voxels - 1)
    return i0, np.minimum(i0 + 1, n_voxels - 1), x - i0


def _lattice_values(grid, lattice_zyx):
    """The trilinear field of ``grid`` [nz, ny, nx] at the centres of a lattice of
    lattice_zyx points over the box: an array of that shape."""
    a = np.asarray(grid, np.float64)
    for axis in (2, 1, 0):
        n = lattice_zyx[axis]
        i0, i1, f = _axis_weights(a.shape[axis], (np.arange(n) + 0.5) / n)
        shape = [1, 1, 1]
        shape[axis] = n
        f = f.reshape(shape)
        a = np.take(a, i0, axis=axis) * (1.0 - f) + np.take(a, i1, axis=axis) * f
    return a


def _cell_means(values, res):
    """Means of a lattice of values over the cells of res (each axis a multiple of it)."""
    cz, cy, cx = res
    nz, ny, nx = values.shape
    return values.reshape(cz, nz // cz, cy, ny // cy, cx, nx // cx).mean(axis=(1, 3, 5))


def _luminance_source(record, field, table, density, bound):
    """luminance(sigma_a Le) for emission field values ``field`` and extinction ``density``
    (arrays of one shape; 1/unit), Le through the blackbody table's running maximum at the
    next entry up when ``bound`` (an upper bound), else as the renderer interpolates it.
    Luminance is linear and its weights are not negative, so the table is reduced to one
    luminance per row first: the interpolation is the same, and the running maximum of the
    luminance bounds it (more tightly than the channels' own maxima would)."""
    ka = (1.0 - np.asarray(record["albedo"], np.float64)) * np.asarray(record["chroma"],
                                                                        np.float64)
    weights = np.asarray(record["emission_rgb"], np.float64) * np.asarray(LUMINANCE_RGB) * ka
    if int(record["emission_kind"]) == EMISSION_RADIANCE:
        return np.maximum(field, 0.0) * (float(weights.sum()) * density)
    lum = np.asarray(table, np.float64)[:BLACKBODY_TABLE_SIZE] @ weights
    x = np.clip(field * float(record["table_scale"]), 0.0, BLACKBODY_TABLE_SIZE - 1.0)
    if bound:
        row = np.minimum(np.floor(x).astype(np.int64) + 1, BLACKBODY_TABLE_SIZE - 1)
        return np.maximum.accumulate(lum)[row] * density
    i0 = np.minimum(x.astype(np.int64), BLACKBODY_TABLE_SIZE - 2)
    w = x - i0
    return (lum[i0] * (1.0 - w) + lum[i0 + 1] * w) * density


def emitter_weights(record, stored, emis, table):
    """(weights [cz, cy, cx], res (cz, cy, cx)) of the cells of the medium of ``record`` (a
    ``medium_dtype`` record), whose density is ``stored`` (density_storage: an array, a
    BrickGrid, or None) and whose emission field grid and table are ``emis`` and
    ``table`` (module docstring)."""
    from .reference.majorant import build_majorant_grid
    from .reference.sparse_grid import majorant_from_bricks
    kind = int(record["density_kind"])
    scale = float(record["scale"])
    dims = [tuple(int(n) for n in emis.shape)]
    if kind in (DENSITY_GRID, DENSITY_BRICKS):
        dims.append(tuple(int(x) for x in record["dims"])[::-1])
    finest = tuple(max(d[a] for d in dims) for a in range(3))
    res = _resolution(finest)
    # Upper bounds per cell: the majorant grid's construction for each field.
    if kind == DENSITY_GRID:
        mu_max = build_majorant_grid(np.asarray(stored), res, minima=False)[0].astype(np.float64) * scale
    elif kind == DENSITY_BRICKS:
        mu_max = np.asarray(majorant_from_bricks(stored.table, stored.pool, stored.dims, res)[0],
                            np.float64) * scale
    elif kind == DENSITY_CONSTANT:
        mu_max = np.full(res, float(record["density"]) * scale)
    else:   # 1-D profiles: the global bound
        mu_max = np.full(res, float(record["sigma_maj"]))
    f_max = build_majorant_grid(np.asarray(emis), res, minima=False)[0].astype(np.float64)
    bound = _luminance_source(record, f_max, table, mu_max, True)
    # Means over a lattice with a point per voxel (at least 2 per cell and axis).
    lattice = tuple(r * max(2, min(-(-f // r), MAX_LATTICE // r)) for r, f in zip(res, finest))
    field = _lattice_values(emis, lattice)
    if kind == DENSITY_GRID:
        mean = _cell_means(_luminance_source(record, field, table,
                                             _lattice_values(stored, lattice) * scale, False),
                           res)
    else:   # constant: exact; bricks and profiles: the cell's density bound
        mean = _cell_means(_luminance_source(record, field, table, np.ones(lattice), False),
                           res) * mu_max
    bound = np.where(np.isfinite(bound) & (bound > 0.0), bound, 0.0)
    mean = np.where(np.isfinite(mean) & (mean > 0.0), mean, 0.0)
    if not mean.sum() > 0.0:
        return bound, res
    # The bound's share keeps every cell where sigma_a Le can be positive in the support.
    return mean + SUPPORT_SHARE * (mean.sum() / max(bound.sum(), 1e-300)) * bound, res


def _det3(xform):
    a = np.asarray(xform, np.float64).reshape(3, 4)[:, :3]
    return abs(float(np.linalg.det(a)))


def _inverse_map(record):
    """Medium space to the scene frame, 3x4 row-major (the inverse of the record's xform)."""
    if not int(record["transformed"]):
        return np.concatenate([np.eye(3), np.zeros((3, 1))], axis=1).ravel()
    m = np.asarray(record["xform"], np.float64).reshape(3, 4)
    inv = np.linalg.inv(m[:, :3])
    return np.concatenate([inv, (-inv @ m[:, 3])[:, None]], axis=1).ravel()


def attach_emitters(records, stored, emis, tables, real):
    """Builds every emitting medium's distribution: sets the emitter fields of ``records``
    (one ``medium_dtype`` record per medium, in place) and returns the media's tables
    (given in float64, whatever ``real``) with the cells appended, as ``real`` arrays.
    Returns (tables, total): total is the summed weight x volume, 0 when no medium has
    anything to sample (emission sampling then stays off)."""
    per = []
    for rec, s, e, t in zip(records, stored, emis, tables):
        rec["emitter_res"] = (0, 0, 0)
        rec["emitter_prob"] = 0.0
        rec["emitter_density"] = 0.0
        rec["emitter_row"] = 0
        rec["emitter_to_scene"] = _inverse_map(rec)
        if int(rec["emission_kind"]) == EMISSION_NONE:
            per.append(None)
            continue
        w, res = emitter_weights(rec, s, e, t)
        extent = np.asarray(rec["bmax"], np.float64) - np.asarray(rec["bmin"], np.float64)
        local_cell = float(np.prod(extent)) / float(np.prod(res))
        det = _det3(rec["xform"]) if int(rec["transformed"]) else 1.0
        power = float(w.sum()) * local_cell / det
        per.append((w, res, local_cell, det, power) if power > 0.0 and np.isfinite(power)
                   else None)
    total = sum(x[4] for x in per if x is not None)
    out = []
    for rec, t, x in zip(records, tables, per):
        if x is None or not total > 0.0:
            out.append(np.ascontiguousarray(t, dtype=real))
            continue
        w, res, local_cell, det, power = x
        flat = w.ravel()   # [cz, cy, cx] C order: c = ix + cx (iy + cy iz)
        threshold, alias = alias_table(flat)
        prob = flat / flat.sum()
        rows = np.stack([threshold, alias.astype(np.float64), prob], axis=1)
        rec["emitter_row"] = t.shape[0]
        rec["emitter_res"] = (res[2], res[1], res[0])
        rec["emitter_prob"] = power / total
        rec["emitter_density"] = (power / total) * det / local_cell
        out.append(np.ascontiguousarray(np.concatenate([np.asarray(t, np.float64), rows]),
                                        dtype=real))
    return out, total
