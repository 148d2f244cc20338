"""The medium: what is here (density, extinction) and what bounds it along a ray (segments).

Twin of ``kernels/medium.h``. A medium is a record (``params.MEDIUM_FIELDS``, a numpy
structured record) plus the arrays it points to, carried together as ``MediumData``
(m, grid, maj, mnr, ..., rec); the kernels' ``MediumData`` struct holds the same things.

* **Density sources** (``m.density_kind``): ``DENSITY_CONSTANT`` (``m.density`` everywhere:
  a homogeneous medium), ``DENSITY_GRID`` (trilinear in ``grid``, see grid.py),
  ``DENSITY_BRICKS`` (the same values from 8^3 bricks, sparse_grid.py), or a 1-D
  test profile of the x coordinate alone, with parameters a, b, c, s, L = ``m.profile``:

  =====================  ============================================  ===================
  kind                   density(x)                                    parameters
  =====================  ============================================  ===================
  DENSITY_RAMP           a + (b - a) x / L                             a, b >= 0
  DENSITY_GAUSS_BUMP     a + b exp(-(x - c)^2 / (2 s^2))               a, b >= 0
  DENSITY_GAUSS_HOLE     max(a - b exp(-(x - c)^2 / (2 s^2)), 0)       0 <= b <= a
  DENSITY_COSINE         a (1 + b cos(2 pi c x / L + s))               a >= 0, 0 <= b <= 1
  =====================  ============================================  ===================

  Along the test ray o = 0, d = +x the profile's x is the ray parameter t, so the closed
  forms below (``optical_depth_profile``) give exact transmittances.
* **Extinction** is ``m.scale * density``, per world unit; ``extinction_in`` (the media of a
  segment) and ``extinction`` (the media whose box holds the point) are the one counted
  query every technique uses (one ``C_LOOKUPS`` per medium read; a value above the
  segment's majorant is counted in ``C_OVER_MAJORANT``, never silently accepted).
* **Majorant segments** (``m.majorant_kind``): ``majorant_iter_init`` / ``majorant_next`` walk
  a ray segment [t0, t1] and yield (t_min, t_max, sigma_maj, sigma_min, media) pieces that
  tile it (``media``: the set of media that cover the piece, 1 for one medium),
  with sigma_min <= extinction <= sigma_maj on each. ``MAJORANT_GLOBAL`` is one piece with
  the record's ``sigma_maj`` and ``sigma_min``; ``MAJORANT_GRID`` yields one piece per cell of
  the majorant grid crossed by the 3-D DDA (dda.py), scale times the cell's density maximum
  and minimum (majorant.py); ``MAJORANT_OCTREE`` yields one piece per octree leaf crossed
  (octree.py), in order, scale times the leaf's maximum and minimum. Pieces with sigma_maj <= 0 (nothing there) and pieces of zero
  length are skipped: an empty cell costs nothing. A piece with sigma_min == sigma_maj is
  homogeneous, and tracking treats it exactly (tracking.py).

  The bounds are trusted: sigma_min must be a true minorant and sigma_maj a true majorant of
  the extinction on the piece (pack.py builds them so: majorant.py takes the extremes over
  every voxel trilinear interpolation can read). A majorant that is too low is caught by
  ``extinction``'s count wherever a lookup happens; a minorant that is too high, or a density
  edited after the bounds were built over a homogeneous piece, is not, since those decisions
  make no lookup.

Adding a source or a structure (RGB extinction, an emission field, the octree of majorants)
adds a kind here and in medium.h, and every technique built on these three functions
inherits it.
"""

import math
from collections import namedtuple

import numpy as np
from numba import njit

from ..constants import (MAX_MEDIA, BLACKBODY_TABLE_SIZE, COMB_COUNT_LIMIT, DENSITY_BRICKS, DENSITY_CONSTANT, DENSITY_COSINE,
                         DENSITY_GAUSS_BUMP, DENSITY_GAUSS_HOLE, DENSITY_GRID, DENSITY_RAMP,
                         EMISSION_NONE, EMISSION_RADIANCE, MAJORANT_GLOBAL, MAJORANT_GRID, MAJORANT_OCTREE,
                         OVER_MAJORANT_SLACK, TWO_PI)
from ..params import C_CAPPED, C_LOOKUPS, C_OVER_MAJORANT, medium_dtype
from .dda import DDA_STATE_SIZE, dda_init, dda_next
from .grid import grid_lookup
from .octree import OCTREE_STATE_SIZE, octree_init, octree_next
from .rng import rng_next
from .sparse_grid import sparse_lookup
from .vec import madd3

#: A medium record with its arrays. Every function below takes the scene's media, ``med``:
#: a tuple of these, one per medium (its length is the kernels' MEDIA_COUNT); ``(med, i)``
#: names medium i. The arrays: the density grid [nz, ny, nx], the majorant grid's
#: per-cell density maxima and minima [cz, cy, cx] (an octree's: per node, [1, 1, n_nodes]),
#: the emission field grid [nz, ny, nx], the blackbody table [BLACKBODY_TABLE_SIZE, 3], a
#: brick grid's index table int32 [bz, by, bx] and pool [n_slots, 8, 8, 8], and an octree's
#: first-child indices int32 [n_nodes] (octree.py) (small placeholders when unused), and
#: the record of the transmittance segments this pixel's samples query, [K + 1, 9]
#: (``record_segment``; a [1, 9] placeholder when not recording).
MediumData = namedtuple("MediumData", ["m", "grid", "maj", "mnr", "emis", "table", "bricks",
                                       "pool", "nodes", "rec"])

#: The index of the first medium, as jitted code must pass it: Numba types a literal 0
#: passed on as an index into the media tuple by compiling a getter that returns the
#: medium's record, which it cannot do; np.intp(0) is an ordinary integer.
ZERO = np.intp(0)

#: Iterator state: [done, t0, t1, unused] then the DDA's or the octree walk's state.
ITER_STATE_SIZE = 4 + max(DDA_STATE_SIZE, OCTREE_STATE_SIZE)


@njit(cache=True)
def profile_density(kind, prof, x):
    """Density of a 1-D test profile at coordinate x (parameters prof = a, b, c, s, L)."""
    a, b, c, s, L = prof[0], prof[1], prof[2], prof[3], prof[4]
    if kind == DENSITY_RAMP:
        return a + (b - a) * x / L
    if kind == DENSITY_GAUSS_BUMP:
        y = (x - c) / s
        return a + b * math.exp(-0.5 * y * y)
    if kind == DENSITY_GAUSS_HOLE:
        y = (x - c) / s
        return max(a - b * math.exp(-0.5 * y * y), 0.0)
    return a * (1.0 + b * math.cos(TWO_PI * c * x / L + s))


@njit(cache=True)
def to_medium(m, p):
    """Point p of the scene frame in the medium's own space, where its box, grids and
    majorants live: p itself unless a transform places the medium (``m.transformed``; the
    packing is in pack.medium_space)."""
    if not m.transformed:
        return p
    x = m.xform
    return (x[0] * p[0] + x[1] * p[1] + x[2] * p[2] + x[3],
            x[4] * p[0] + x[5] * p[1] + x[6] * p[2] + x[7],
            x[8] * p[0] + x[9] * p[1] + x[10] * p[2] + x[11])


@njit(cache=True)
def to_medium_dir(m, d):
    """Direction d of the scene frame in the medium's space, not renormalised: o + t d maps
    to to_medium(o) + t to_medium_dir(d), so t stays a distance of the scene frame and
    extinction stays per unit of it."""
    if not m.transformed:
        return d
    x = m.xform
    return (x[0] * d[0] + x[1] * d[1] + x[2] * d[2],
            x[4] * d[0] + x[5] * d[1] + x[6] * d[2],
            x[8] * d[0] + x[9] * d[1] + x[10] * d[2])


@njit(cache=True)
def density_at(med, i, q):
    """Density of medium i at q, a point of its own space (no box test)."""
    md = med[i]
    m = md.m
    kind = m.density_kind
    if kind == DENSITY_GRID:
        return grid_lookup(md.grid, (m.bmin[0], m.bmin[1], m.bmin[2]),
                           (m.inv_extent[0], m.inv_extent[1], m.inv_extent[2]), q)
    if kind == DENSITY_BRICKS:
        return sparse_lookup(md.bricks, md.pool, (m.dims[0], m.dims[1], m.dims[2]),
                             (m.bmin[0], m.bmin[1], m.bmin[2]),
                             (m.inv_extent[0], m.inv_extent[1], m.inv_extent[2]), q)
    if kind == DENSITY_CONSTANT:
        return m.density
    return profile_density(kind, m.profile, q[0])


@njit(cache=True)
def in_box(m, q):
    """True if q (the medium's space) lies in the medium's box, faces included."""
    return (m.bmin[0] <= q[0] <= m.bmax[0] and m.bmin[1] <= q[1] <= m.bmax[1]
            and m.bmin[2] <= q[2] <= m.bmax[2])


@njit(cache=True)
def has_medium(bits, i):
    """True if bit i (medium i) is set in ``bits``, a set of media (``media_at``,
    ``media_near``, a segment's ``media``)."""
    return (bits >> i) & 1 != 0


#: The reciprocal the near test takes for a zero direction component: the largest float
#: (FLT_MAX in the kernels), so that slab gives +-inf or 0 and never 0 * inf.
_NEAR_INV_ZERO = float(np.finfo(np.float64).max)


@njit(cache=True)
def media_near(med, o, d, t_lo, t_hi):
    """The media whose near box (``m.near_min``, ``m.near_max``: a box of the scene frame a
    little larger than the medium's placed box, pack.near_box) the segment [t_lo, t_hi] of
    o + t d touches, a bit per medium. A ray that misses a medium's near box misses the
    medium, so its box test and its walk can be skipped: with many media apart, each costs
    a ray that passes it by one cheap slab test (no transform, the direction's reciprocal
    shared) instead of its own ray_box in its space. One medium: 1, as in the kernels, whose
    one-medium build has no near test."""
    if len(med) == 1:
        return 1
    inv = (_NEAR_INV_ZERO if d[0] == 0.0 else 1.0 / d[0],
           _NEAR_INV_ZERO if d[1] == 0.0 else 1.0 / d[1],
           _NEAR_INV_ZERO if d[2] == 0.0 else 1.0 / d[2])
    bits = 0
    for i in range(len(med)):
        m = med[i].m
        t0, t1 = t_lo, t_hi
        for a in range(3):
            ta = (m.near_min[a] - o[a]) * inv[a]
            tb = (m.near_max[a] - o[a]) * inv[a]
            t0 = max(t0, min(ta, tb))
            t1 = min(t1, max(ta, tb))
        if t0 <= t1:
            bits |= 1 << i
    return bits


@njit(cache=True)
def medium_extinction(med, i, p, counters):
    """Extinction of medium i alone at p (its largest channel), a counted lookup wherever p
    is: a point a rounding outside the box reads the box's edge (lookups clamp)."""
    md = med[i]
    counters[C_LOOKUPS] += 1
    return md.m.scale * density_at(med, i, to_medium(md.m, p))


@njit(cache=True)
def extinction_in(med, media, p, sigma_maj, counters):
    """Extinction at p (1/world unit) of the media in ``media`` (a bit per medium), summed:
    one counted lookup each, no box tests. Tracking passes its segment's media (those whose
    own segments cover it, ``majorant_next``), so a lookup sums exactly the media the
    segment's majorant sums, and a medium the segment does not cover costs nothing. One
    medium ignores ``media``. A value above the majorant sigma_maj of the segment being
    tracked by more than OVER_MAJORANT_SLACK of it is counted."""
    if len(med) == 1:
        mu = medium_extinction(med, ZERO, p, counters)
    else:
        mu = 0.0
        for i in range(len(med)):
            if has_medium(media, i):
                mu += medium_extinction(med, i, p, counters)
    if mu > sigma_maj * (1.0 + OVER_MAJORANT_SLACK):
        counters[C_OVER_MAJORANT] += 1
    return mu


@njit(cache=True)
def media_at(med, p):
    """The media whose box holds p, a bit per medium (one medium: 1)."""
    if len(med) == 1:
        return 1
    bits = 0
    for i in range(len(med)):
        m = med[i].m
        if in_box(m, to_medium(m, p)):
            bits |= 1 << i
    return bits


@njit(cache=True)
def extinction(med, p, sigma_maj, counters):
    """Extinction at a point of no segment: ``extinction_in`` of every medium whose box holds
    p (one medium: one lookup)."""
    return extinction_in(med, media_at(med, p), p, sigma_maj, counters)


@njit(cache=True)
def medium_chroma(med):
    """Extinction per channel relative to ``extinction`` (the largest channel's): RGB. Several
    media share it (schema.py requires it)."""
    c = med[0].m.chroma
    return (c[0], c[1], c[2])


@njit(cache=True)
def emitted_radiance(med, i, p):
    """Emitted radiance Le of medium i at point p of the scene frame, RGB: ``emission_rgb`` x
    field(p) for EMISSION_RADIANCE; ``emission_rgb`` x the blackbody table at temperature(p)
    (linear in kelvin between entries, 0 at or below 0 K, the last entry above the table) for
    EMISSION_TEMPERATURE. The field is trilinear in the emission grid over the medium box."""
    md = med[i]
    m = md.m
    e = m.emission_rgb
    p = to_medium(m, p)
    f = grid_lookup(md.emis, (m.bmin[0], m.bmin[1], m.bmin[2]),
                    (m.inv_extent[0], m.inv_extent[1], m.inv_extent[2]), p)
    if m.emission_kind == EMISSION_RADIANCE:
        return (e[0] * f, e[1] * f, e[2] * f)
    x = min(max(f * m.table_scale, 0.0), BLACKBODY_TABLE_SIZE - 1.0)
    i0 = min(int(x), BLACKBODY_TABLE_SIZE - 2)
    w = x - i0
    tb = md.table
    return (e[0] * (tb[i0, 0] * (1.0 - w) + tb[i0 + 1, 0] * w),
            e[1] * (tb[i0, 1] * (1.0 - w) + tb[i0 + 1, 1] * w),
            e[2] * (tb[i0, 2] * (1.0 - w) + tb[i0 + 1, 2] * w))


@njit(cache=True)
def majorant_cell(q, bmin, inv_extent, n):
    """The cell, of n along this axis, that coordinate q of the medium's space falls in."""
    return min(max(int(math.floor((q - bmin) * inv_extent * n)), 0), n - 1)


@njit(cache=True)
def majorant_at(med, p):
    """The majorant at point p of the scene frame: the sum over the media whose box holds p
    of their majorant there -- the grid cell's or the octree leaf's maximum times the scale,
    or the global one -- which is the sigma_maj of the merged segment that covers p (0 where
    none does)."""
    s = 0.0
    for i in range(len(med)):
        md = med[i]
        m = md.m
        q = to_medium(m, p)
        if len(med) > 1 and not in_box(m, q):
            continue
        if m.majorant_kind == MAJORANT_GRID:
            cz, cy, cx = m.maj_res[0], m.maj_res[1], m.maj_res[2]
            s += m.scale * md.maj[majorant_cell(q[2], m.bmin[2], m.inv_extent[2], cz),
                                  majorant_cell(q[1], m.bmin[1], m.inv_extent[1], cy),
                                  majorant_cell(q[0], m.bmin[0], m.inv_extent[0], cx)]
        elif m.majorant_kind == MAJORANT_OCTREE:
            n = 1 << m.octree_depth
            ix = majorant_cell(q[0], m.bmin[0], m.inv_extent[0], n)
            iy = majorant_cell(q[1], m.bmin[1], m.inv_extent[1], n)
            iz = majorant_cell(q[2], m.bmin[2], m.inv_extent[2], n)
            node = 0
            level = 0
            while level < m.octree_depth and md.nodes[node] != 0:
                k = m.octree_depth - 1 - level
                node = md.nodes[node] + (((ix >> k) & 1) | (((iy >> k) & 1) << 1)
                                         | (((iz >> k) & 1) << 2))
                level += 1
            s += m.scale * md.maj[0, 0, node]
        else:
            s += m.sigma_maj
    return s


@njit(cache=True)
def media_emit(med):
    """True if some medium emits."""
    for i in range(len(med)):
        if med[i].m.emission_kind != EMISSION_NONE:
            return True
    return False


@njit(cache=True)
def medium_pick(med, p, rng, counters):
    """The medium a real collision at p chose: medium i with probability mu_i / sum(mu), its
    share of the extinction that decided the event (every medium's real collisions, summed,
    are the scene's). A point in one box alone takes that medium without a lookup (in none,
    by rounding: medium 0); elsewhere every medium whose box holds p is looked up (counted),
    and a uniform is drawn only where two or more have extinction, so one medium, and media
    that do not overlap, draw nothing."""
    n = len(med)
    if n == 1:
        return ZERO
    bits = media_at(med, p)
    boxes = 0
    only = ZERO
    for i in range(n):
        if has_medium(bits, i):
            boxes += 1
            only = i
    if boxes < 2:   # one box holds p (none, by rounding: medium 0): no lookup
        return only
    mu = np.empty(n)
    total = 0.0
    present = 0
    for i in range(n):
        mu[i] = medium_extinction(med, i, p, counters) if has_medium(bits, i) else 0.0
        total += mu[i]
        if mu[i] > 0.0:
            present += 1
    x = rng_next(rng) * total if present >= 2 else 0.0
    acc = 0.0
    last = 0
    for i in range(n):
        acc += mu[i]
        if mu[i] > 0.0:
            last = i
            if x < acc:
                return i
    return last


@njit(cache=True)
def medium_iter_init(it, med, i, o, d, t0, t1):
    """Start medium i's walk of the majorant segments of ray o + t d over [t0, t1] (state
    ``it``, ITER_STATE_SIZE). With several media the segment is first clipped to medium i's
    box (one medium's rays were clipped by enter_media)."""
    m = med[i].m
    o, d = to_medium(m, o), to_medium_dir(m, d)
    if len(med) > 1:
        te, tx = ray_box(o, d, m.bmin, m.bmax)
        t0, t1 = max(t0, te), min(t1, tx)
    it[0] = 0.0 if t1 > t0 else 1.0
    it[1] = t0
    it[2] = t1
    if m.majorant_kind == MAJORANT_GRID:
        dda_init(it[4:], o, d, t0, t1, (m.bmin[0], m.bmin[1], m.bmin[2]),
                 (m.bmax[0], m.bmax[1], m.bmax[2]), (m.maj_res[0], m.maj_res[1], m.maj_res[2]))
    elif m.majorant_kind == MAJORANT_OCTREE:
        octree_init(it[4:], o, d, t0, t1, (m.bmin[0], m.bmin[1], m.bmin[2]),
                    (m.bmax[0], m.bmax[1], m.bmax[2]), m.octree_depth)


@njit(cache=True)
def medium_iter_next(it, med, i):
    """Medium i's next non-empty segment: (ok, t_min, t_max, sigma_maj, sigma_min); ok is
    False at the end. Segments tile [t0, t1] in order; empty and zero-length ones are
    skipped."""
    md = med[i]
    m = md.m
    if m.majorant_kind == MAJORANT_GRID:
        while True:
            ok, ta, tb, iz, iy, ix = dda_next(it[4:])
            if not ok:
                return False, 0.0, 0.0, 0.0, 0.0
            s_maj = m.scale * md.maj[iz, iy, ix]
            if s_maj > 0.0 and tb > ta:
                return True, ta, tb, s_maj, m.scale * md.mnr[iz, iy, ix]
    if m.majorant_kind == MAJORANT_OCTREE:
        while True:
            ok, ta, tb, node = octree_next(it[4:], md.nodes, (m.bmin[0], m.bmin[1], m.bmin[2]),
                                           (m.bmax[0], m.bmax[1], m.bmax[2]), m.octree_depth)
            if not ok:
                return False, 0.0, 0.0, 0.0, 0.0
            s_maj = m.scale * md.maj[0, 0, node]
            if s_maj > 0.0 and tb > ta:
                return True, ta, tb, s_maj, m.scale * md.mnr[0, 0, node]
    if it[0] != 0.0:
        return False, 0.0, 0.0, 0.0, 0.0
    it[0] = 1.0
    if not m.sigma_maj > 0.0:
        return False, 0.0, 0.0, 0.0, 0.0
    return True, it[1], it[2], m.sigma_maj, m.sigma_min


#: Per medium of several, after its walk's state: [has, t_min, t_max, sigma_maj, sigma_min]
#: of its pending segment; the merge's position t comes last.
_PENDING = 5


@njit(cache=True)
def iter_state_size(n):
    """Floats of the state of majorant_iter_init / majorant_next for n media."""
    return ITER_STATE_SIZE if n == 1 else n * (ITER_STATE_SIZE + _PENDING) + 1


@njit(cache=True)
def new_iter(med):
    """An uninitialised iterator state for the media ``med``."""
    return np.empty(iter_state_size(len(med)))


@njit(cache=True)
def majorant_iter_init(it, med, o, d, t0, t1):
    """Start walking the majorant segments of ray o + t d over [t0, t1] through every medium
    (state ``it``: ``new_iter(med)``)."""
    majorant_iter_init_near(it, med, o, d, t0, t1, media_near(med, o, d, t0, t1))


@njit(cache=True)
def majorant_iter_init_near(it, med, o, d, t0, t1, near):
    """majorant_iter_init given the media the segment comes near (``media_near``, or a
    superset: enter_media_near's, of the whole ray); a medium outside ``near`` starts no
    walk."""
    n = len(med)
    if n == 1:
        medium_iter_init(it, med, ZERO, o, d, t0, t1)
        return
    w = ITER_STATE_SIZE + _PENDING
    for i in range(n):
        it[i * w + ITER_STATE_SIZE] = 0.0
        if has_medium(near, i):
            medium_iter_init(it[i * w:i * w + ITER_STATE_SIZE], med, i, o, d, t0, t1)
        else:   # a medium the ray passes by: its walk is over before it starts
            it[i * w] = 1.0
    it[n * w] = t0


@njit(cache=True)
def majorant_next(it, med):
    """Next non-empty segment of the media: (ok, t_min, t_max, sigma_maj, sigma_min, media);
    ok is False at the end. One medium: its own segments, media 1. Several: each medium's
    segments merged into pieces from the nearest point at or after the merge's position
    where some medium has a segment to the nearest point where one begins or ends, with the
    sums of the majorants and minorants of the media whose segment covers the piece (outside
    its box, or in an empty cell of its own, a medium adds nothing) and those media as
    ``media``, a bit each. Tracking then sees one ordinary walk, and the extinction it looks
    up is the sum over ``media`` (``extinction_in``): exactly what the majorant bounds."""
    n = len(med)
    if n == 1:
        ok, ta, tb, s_maj, s_min = medium_iter_next(it, med, ZERO)
        return ok, ta, tb, s_maj, s_min, 1
    w = ITER_STATE_SIZE + _PENDING
    t = it[n * w]
    start = math.inf
    for i in range(n):
        b = i * w + ITER_STATE_SIZE
        # Passed: the medium's next segment, unless its walk is over (its done flag, it[0]
        # of its state: no segment, or none left).
        if not (it[b] != 0.0 and it[b + 2] > t):
            it[b] = 0.0
            if it[i * w] == 0.0:
                ok, ta, tb, s_maj, s_min = medium_iter_next(it[i * w:b], med, i)
                if ok:
                    it[b] = 1.0
                    it[b + 1], it[b + 2], it[b + 3], it[b + 4] = ta, tb, s_maj, s_min
                else:
                    it[i * w] = 1.0
        if it[b] != 0.0:
            start = min(start, max(it[b + 1], t))
    if start == math.inf:
        return False, 0.0, 0.0, 0.0, 0.0, 0
    end = math.inf
    s_maj = 0.0
    s_min = 0.0
    media = 0
    for i in range(n):
        b = i * w + ITER_STATE_SIZE
        if it[b] != 0.0:
            if it[b + 1] <= start:
                end = min(end, it[b + 2])
                s_maj += it[b + 3]
                s_min += it[b + 4]
                media |= 1 << i
            else:
                end = min(end, it[b + 1])
    it[n * w] = end
    return True, start, end, s_maj, s_min, media


@njit(cache=True)
def comb_count(x):
    """The points of a comb asked for x of them: ceil(x), at least 1, and at most
    COMB_COUNT_LIMIT (the largest float32 below 2^31: float-to-int conversion past it is
    undefined in the kernels; every estimator caps its points at max_steps anyway)."""
    return max(1, int(math.ceil(min(x, COMB_COUNT_LIMIT))))


@njit(cache=True)
def optical_depth_comb(med, o, d, t0, L, n, u, sigma_maj, counters):
    """Jittered equidistant estimate of the optical depth over [t0, t0 + L] along o + t d:
    (L / n) sum_j mu(t0 + (j + u) L / n), n counted lookups. Unbiased for any n, and exact
    when the extinction is constant, whatever u is."""
    h = L / n
    s = 0.0
    for j in range(n):
        t = t0 + (j + u) * h
        s += extinction(med, madd3(o, d, t), sigma_maj, counters)
    return s * h


@njit(cache=True)
def segment_degenerate(L, mbar, counters, max_steps, min_steps):
    """True if a per-segment estimator returns 1 without a lookup: an empty segment (L or
    mbar not > 0), or max_steps below the min_steps it needs (counted in C_CAPPED)."""
    if not (L > 0.0) or not (mbar > 0.0):
        return True
    if max_steps < min_steps:
        counters[C_CAPPED] += 1
        return True
    return False


@njit(cache=True)
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


@njit(cache=True)
def record_segment(med, o, d, t0, t1, kind):
    """Append the transmittance segment (o, d, t0, t1) of kind ``kind`` (RECORD_CAMERA,
    RECORD_SHADOW) to the pixel's record ``med.rec`` [K + 1, 9]: row 0 holds the count so far
    (column 0) and the capacity K (column 1, set by the host); rows 1..K hold o(3), d(3), t0,
    t1, kind, the layout of the estimator runners' rays. A full record or the [1, 9]
    placeholder records nothing. No random number is drawn, so a recording render is the
    same render. The record is the first medium's (``med`` a tuple of MediumData)."""
    rec = med[0].rec
    if rec.shape[0] <= 1:
        return
    n = int(rec[0, 0])
    if n >= rec[0, 1]:
        return
    row = rec[n + 1]
    row[0], row[1], row[2] = o[0], o[1], o[2]
    row[3], row[4], row[5] = d[0], d[1], d[2]
    row[6], row[7], row[8] = t0, t1, kind
    rec[0, 0] = n + 1


# --- Host-side constructors and closed forms (tests and the estimator benchmark) ------------

@njit(cache=True)
def no_field_arrays():
    """(emis, table, bricks, pool, nodes, rec): placeholders of the emission grid, blackbody
    table, brick arrays, octree nodes and segment record for a medium that does not emit,
    has no brick grid and no octree, and records nothing (tests, benchmarks)."""
    return (np.zeros((1, 1, 1)), np.zeros((2, 3)), np.zeros((1, 1, 1), np.int32),
            np.zeros((1, 8, 8, 8)), np.zeros(1, np.int32), np.zeros((1, 9)))


def medium_data(m, grid, maj, mnr):
    """The media of one medium, ``(MediumData,)``, of record ``m``, density grid ``grid``
    and majorant grid (maj, mnr), float64, with ``no_field_arrays`` for the rest (host side;
    jitted code calls ``no_field_arrays`` and builds the tuple itself)."""
    return (MediumData(m, grid, maj, mnr, *no_field_arrays()),)


def media_data(pk):
    """The media of a packed scene (pack.pack_scene, float64) as the reference takes them: a
    tuple of ``MediumData``, one per medium, each with a placeholder segment record.

    Several media fill MEDIA_SLOTS[0] = 4 slots, or MAX_MEDIA = 8 when there are more, the
    ones past the scene's with ``absent_medium``: Numba compiles the integrator once per
    tuple type, and every scene of 2 to 4 media then shares one compilation, every scene of 5
    to 8 another (one medium keeps its own tuple and the code specialised for it). Each slot
    costs compile time (Numba indexes a tuple through a branch per element): 190 s for 2
    media, 369 s for 8, on the 2-core test machine. An absent medium is never entered, holds
    no point and draws no random number, so the paths and sums are those of the scene's media
    alone."""
    rec = np.zeros((1, 9))
    f, i = np.ascontiguousarray, np.int32   # one type for every medium: a tuple Numba indexes
    media = [MediumData(a.medium[0], f(a.grid, float), f(a.maj, float), f(a.mnr, float),
                        f(a.emis, float), f(a.table, float), f(a.bricks, i), f(a.pool, float),
                        f(a.nodes, i), rec) for a in pk.parts]
    if len(media) > 1:
        slots = next(k for k in MEDIA_SLOTS if k >= len(media))
        media += [absent_medium(media[0])] * (slots - len(media))
    return tuple(media)


#: The tuple lengths media_data pads several media to (the last is MAX_MEDIA).
MEDIA_SLOTS = (4, MAX_MEDIA)


def absent_medium(like):
    """A medium slot that holds nothing (media_data): a box of zero size at 1e30 in every
    coordinate, which no ray enters (the slab test's entry never falls before its exit) and
    no point lies in (no lookup), density 0 without emission; arrays of like's types."""
    m = np.zeros(1, like.m.dtype)
    m[0] = new_medium()
    m[0]["bmin"] = m[0]["bmax"] = (1e30, 1e30, 1e30)
    m[0]["near_min"] = m[0]["near_max"] = (1e30, 1e30, 1e30)
    m[0]["chroma"] = like.m["chroma"]
    z = [np.zeros((1,) * a.ndim, a.dtype) for a in like[1:-1]]
    return MediumData(m[0], *z, like.rec)


def new_medium():
    """A zeroed float64 medium record (a 0-d structured array), no majorant, unit scale."""
    m = np.zeros((), medium_dtype(np.float64))
    m["scale"] = 1.0
    m["dims"] = (1, 1, 1)
    m["maj_res"] = (1, 1, 1)
    m["majorant_kind"] = MAJORANT_GLOBAL
    m["chroma"] = (1.0, 1.0, 1.0)
    m["emission_dims"] = (1, 1, 1)
    return m


def make_profile(kind, a, b=0.0, c=0.0, s=1.0, L=1.0):
    """Medium record of a 1-D profile (DENSITY_CONSTANT: density a everywhere), scale 1, so
    its extinction is the profile itself. Bounds are set by the caller (sigma_maj, sigma_min)."""
    m = new_medium()
    m["density_kind"] = kind
    m["density"] = a if kind == DENSITY_CONSTANT else 0.0
    m["profile"] = (a, b, c, s, L)
    return m


def make_grid_medium(bmin, bmax, scale, dims=(1, 1, 1)):
    """Medium record of a density grid in the box [bmin, bmax] (dims = (nx, ny, nz))."""
    m = new_medium()
    m["density_kind"] = DENSITY_GRID
    m["bmin"], m["bmax"] = bmin, bmax
    m["inv_extent"] = [1.0 / (hi - lo) for lo, hi in zip(bmin, bmax)]
    m["dims"] = dims
    m["scale"] = scale
    return m


def profile_params(med):
    """(kind, a, b, c, s, L) of a profile record (a = the density of a constant one)."""
    kind = int(med["density_kind"])
    a, b, c, s, L = (float(x) for x in med["profile"])
    if kind == DENSITY_CONSTANT:
        a = float(med["density"])
    return kind, a, b, c, s, L


def optical_depth_profile(med, t0, t1):
    """Closed-form integral of a profile's extinction over x in [t0, t1] (float64)."""
    kind, a, b, c, s, L = profile_params(med)
    k_scale = float(med["scale"])
    if kind == DENSITY_CONSTANT:
        return k_scale * a * (t1 - t0)
    if kind == DENSITY_RAMP:
        def F(t):
            return a * t + 0.5 * (b - a) * t * t / L
        return k_scale * (F(t1) - F(t0))
    if kind in (DENSITY_GAUSS_BUMP, DENSITY_GAUSS_HOLE):
        sign = 1.0 if kind == DENSITY_GAUSS_BUMP else -1.0
        g = s * math.sqrt(0.5 * math.pi) * (math.erf((t1 - c) / (s * math.sqrt(2.0)))
                                            - math.erf((t0 - c) / (s * math.sqrt(2.0))))
        return k_scale * (a * (t1 - t0) + sign * b * g)
    if kind == DENSITY_COSINE:
        k = 2.0 * math.pi * c / L
        return k_scale * (a * (t1 - t0) + a * b / k * (math.sin(k * t1 + s) - math.sin(k * t0 + s)))
    raise ValueError(f"not a 1-D profile: kind {kind}")


def profile_bounds(med, t0, t1, n=20001):
    """(minimum, maximum, mean) extinction of a profile over [t0, t1] (dense sampling plus the
    analytic extremes; the maximum is a true majorant, the minimum a true minorant)."""
    kind, a, b, c, s, L = profile_params(med)
    k_scale = float(med["scale"])
    ts = np.linspace(t0, t1, n)
    if kind == DENSITY_CONSTANT:
        vals = np.full(n, a)
    else:
        prof = np.array([a, b, c, s, L])
        vals = np.array([profile_density(kind, prof, t) for t in ts])
    lo, hi = float(vals.min()), float(vals.max())
    if kind == DENSITY_GAUSS_BUMP and t0 <= c <= t1:
        hi = max(hi, a + b)
    if kind == DENSITY_GAUSS_HOLE and t0 <= c <= t1:
        lo = min(lo, max(a - b, 0.0))
    if kind == DENSITY_COSINE:  # the analytic extremes bound every sub-interval
        hi, lo = a * (1 + b), a * (1 - b)
    mean = optical_depth_profile(med, t0, t1) / (t1 - t0)
    return k_scale * lo, k_scale * hi, mean
