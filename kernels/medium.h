/* The media: what is here (density, extinction) and what bounds it along a ray (majorant
 * segments). Twin of volmc/reference/medium.py, where the density sources, the segment
 * convention, the guards and the rules of several media are described. The record type
 * Medium is generated from volmc/params.py (MEDIUM_FIELDS) into params.h. The media are the
 * same for every lane; points, rays and their segments are per lane.
 *
 * A scene holds MEDIA_COUNT media (a build option, default 1; at most MAX_MEDIA). Medium i
 * has its record m[i]; its arrays begin at its record's offsets in buffers the media share.
 * Functions that take (med, i) are medium i's; the others (extinction_in, extinction,
 * media_at, media_near, majorant_iter_init, majorant_next, medium_chroma) are the scene's:
 * where media overlap their coefficients add, the majorant segments are the sums of each
 * medium's, and a segment's lookups read the media that cover it (Segment.media). A
 * one-medium build compiles the code it compiled before several media existed (the same
 * image bit for bit). */
#ifndef VOLMC_MEDIUM_H
#define VOLMC_MEDIUM_H

#include "params.h"
#include "features.h"
#include "lanes.h"
#include "grid.h"
#include "dda.h"
#include "octree.h"
#include "spectrum.h"
#include "rng.h"

#ifndef MEDIA_COUNT
#define MEDIA_COUNT 1
#endif

/* The media with the arrays they point to: per medium (at its record's offsets), the
 * density grid [nz][ny][nx], the majorant grid's per-cell density maxima and minima
 * [cz][cy][cx] (an octree's: per node), the emission field grid [nz][ny][nx], the blackbody
 * table [BLACKBODY_TABLE_SIZE][3], a brick grid's index table [bz][by][bx] and pool
 * [n_slots][8][8][8] (grid.h), and an octree's first-child indices [n_nodes] (octree.h);
 * and the segment record of the whole launch, [pixels][K + 1][RECORD_COLUMNS]
 * (record_segment; 0 when not recording), with each lane's pixel (rec_pixel, -1: none). */
typedef struct {
    Medium m[MEDIA_COUNT]; /* copies: the compiler keeps their fields in registers */
    global const float *grid;
    global const float *maj;
    global const float *mnr;
    global const float *emis;
    global const float *table;
    global const int *bricks;
    global const float *pool;
    global const int *nodes;
    global float *rec;
    int rec_capacity;
    lint rec_pixel;
} MediumData;

/* Returns t_enter, writes t_exit; no hit when t_enter >= t_exit. Zero direction components
 * (including -0.0) are handled without 0 * inf. */
static inline lfloat ray_box(lvec3 o, lvec3 d, float3 bmin, float3 bmax, lfloat *t_exit) {
    lfloat t0 = (lfloat)(-FLT_MAX), t1 = (lfloat)(FLT_MAX); /* "no limit": NO_LIMIT, guards.h */
    lfloat oa[3] = {o.x, o.y, o.z}, da[3] = {d.x, d.y, d.z};
    float lo[3] = {bmin.x, bmin.y, bmin.z}, hi[3] = {bmax.x, bmax.y, bmax.z};
    lmask miss = (lmask)(0);
    LANE_UNROLL for (int a = 0; a < 3; ++a) {
        lmask zero = da[a] == 0.0f;
        miss = miss | (zero & (oa[a] < lo[a] || oa[a] > hi[a]));
        lfloat inv = 1.0f / select(da[a], (lfloat)(1.0f), zero); /* no 1 / 0 in any lane */
        lfloat ta = (lo[a] - oa[a]) * inv;
        lfloat tb = (hi[a] - oa[a]) * inv;
        t0 = select(fmax(t0, fmin(ta, tb)), t0, zero);
        t1 = select(fmin(t1, fmax(ta, tb)), t1, zero);
    }
    *t_exit = select(t1, (lfloat)(-FLT_MAX), miss);
    return select(t0, (lfloat)(FLT_MAX), miss);
}

static inline float3 vec3(const float v[3]) { return (float3)(v[0], v[1], v[2]); }

/* The lanes of `active` whose bit i is set in `bits`. */
static inline lmask has_medium(lint bits, int i, lmask active) {
    return active & (((bits >> i) & 1) != 0);
}

/* The media whose near box (params.py: a box of the scene frame a little larger than the
 * medium's placed box) the segment [t_lo, t_hi] of o + t d touches, a bit per medium in
 * each lane of `active` (twin in medium.py). A ray that misses a near box misses the medium,
 * so a medium near no lane's ray needs no box test and no walk. The test is cheap because it
 * runs for every medium of the scene at every walk's start: no transform, the direction's
 * reciprocal computed once, and min/max without NaN handling. None arises: a zero
 * component's reciprocal is FLT_MAX, so its slab gives +-inf or 0, never 0 * inf (an
 * origin on or inside the slab gets no limit from it, one outside it a limit at or past
 * FLT_MAX, a miss where the near box's margin can tell). */
static inline lint media_near(const MediumData *med, lvec3 o, lvec3 d, lfloat t_lo,
                              lfloat t_hi, lmask active) {
#if MEDIA_COUNT == 1
    return (lint)(1);
#else
    lfloat oa[3] = {o.x, o.y, o.z}, da[3] = {d.x, d.y, d.z}, inv[3];
    LANE_UNROLL for (int a = 0; a < 3; ++a)
        inv[a] = select(1.0f / da[a], (lfloat)(FLT_MAX), da[a] == 0.0f);
    lint bits = (lint)(0);
    _Pragma("unroll") for (int i = 0; i < MEDIA_COUNT; ++i) {
        const Medium *m = &med->m[i];
        lfloat t0 = t_lo, t1 = t_hi;
        LANE_UNROLL for (int a = 0; a < 3; ++a) {
            lfloat ta = (m->near_min[a] - oa[a]) * inv[a];
            lfloat tb = (m->near_max[a] - oa[a]) * inv[a];
            t0 = max(t0, min(ta, tb));
            t1 = min(t1, max(ta, tb));
        }
        bits = bits | select((lint)(0), (lint)(1 << i), active & (t0 <= t1));
    }
    return bits;
#endif
}

static inline lfloat profile_density(int kind, const float prof[5], lfloat x) {
    float a = prof[0], b = prof[1], c = prof[2], s = prof[3], L = prof[4];
    if (kind == DENSITY_RAMP) return a + (b - a) * x / L;
    if (kind == DENSITY_GAUSS_BUMP) {
        lfloat y = (x - c) / s;
        return a + b * exp(-0.5f * y * y);
    }
    if (kind == DENSITY_GAUSS_HOLE) {
        lfloat y = (x - c) / s;
        return fmax(a - b * exp(-0.5f * y * y), 0.0f);
    }
    return a * (1.0f + b * cos(TWO_PI * c * x / L + s));
}

/* Point p of the scene frame in the medium's own space (twin in medium.py): p itself unless a
 * transform places the medium. */
static inline lvec3 to_medium(const Medium *m, lvec3 p) {
    if (!FEATURE_TRANSFORM || !m->transformed) return p;
    const float *x = m->xform;
    return v3(x[0] * p.x + x[1] * p.y + x[2] * p.z + x[3],
              x[4] * p.x + x[5] * p.y + x[6] * p.z + x[7],
              x[8] * p.x + x[9] * p.y + x[10] * p.z + x[11]);
}

/* Direction d in the medium's space, not renormalised: t stays a distance of the scene
 * frame (twin in medium.py). */
static inline lvec3 to_medium_dir(const Medium *m, lvec3 d) {
    if (!FEATURE_TRANSFORM || !m->transformed) return d;
    const float *x = m->xform;
    return v3(x[0] * d.x + x[1] * d.y + x[2] * d.z, x[4] * d.x + x[5] * d.y + x[6] * d.z,
              x[8] * d.x + x[9] * d.y + x[10] * d.z);
}

/* Density of medium i at q, a point of its own space (no box test). */
static inline lfloat density_at(const MediumData *med, int i, lvec3 q, lmask active) {
    const Medium *m = &med->m[i];
    int kind = m->density_kind;
    if (kind == DENSITY_GRID)
        return grid_lookup(med->grid + m->grid_off, (int3)(m->dims[0], m->dims[1], m->dims[2]),
                           vec3(m->bmin), vec3(m->inv_extent), q, active);
    if (kind == DENSITY_BRICKS)
        return sparse_lookup(med->bricks + m->bricks_off, med->pool + m->pool_off,
                             (int3)(m->dims[0], m->dims[1], m->dims[2]), vec3(m->bmin),
                             vec3(m->inv_extent), q, active);
    if (!FEATURE_PROFILES || kind == DENSITY_CONSTANT) return (lfloat)(m->density);
    return profile_density(kind, m->profile, q.x);
}

/* The lanes of `active` whose point q (medium i's space) lies in medium i's box. */
static inline lmask in_box(const Medium *m, lvec3 q, lmask active) {
    return active & (q.x >= m->bmin[0]) & (q.x <= m->bmax[0]) & (q.y >= m->bmin[1]) &
           (q.y <= m->bmax[1]) & (q.z >= m->bmin[2]) & (q.z <= m->bmax[2]);
}

/* Extinction of medium i alone at p (its largest channel), a counted lookup in the lanes of
 * `active` (0 in the others), wherever p is (lookups clamp to the box's edge). */
static inline lfloat medium_extinction(const MediumData *med, int i, lvec3 p, lulong *counters,
                                       lmask active) {
    const Medium *m = &med->m[i];
    counters[C_LOOKUPS] += lane_ones(active);
    return select((lfloat)(0.0f), m->scale * density_at(med, i, to_medium(m, p), active),
                  active);
}

/* The counted lookup of the media in `media` (a bit per medium, per lane; see Segment) at p,
 * in the active lanes (the others' results are not to be used): their extinction summed,
 * without box tests, since a segment's media cover it (a point a rounding outside a box
 * reads the box's edge: lookups clamp). One medium ignores `media`. Always inlined, as
 * rng_next is: PoCL's inliner kept both out of line, and inlining them measured 1.14x and
 * 1.12x samples/s at W = 1 and 16 on an fbm cloud (1.06x and 1.02x on the default cloud). */
static inline __attribute__((always_inline)) lfloat extinction_in(const MediumData *med,
                                                                  lint media, lvec3 p,
                                                                  lfloat sigma_maj,
                                                                  lulong *counters,
                                                                  lmask active) {
#if MEDIA_COUNT == 1
    lfloat mu = med->m[0].scale * density_at(med, 0, to_medium(&med->m[0], p), active);
    counters[C_LOOKUPS] += lane_ones(active);
#else
    lfloat mu = (lfloat)(0.0f);
    int some = lane_or(media, active); /* the media some lane reads: one test per medium */
    for (int i = 0; i < MEDIA_COUNT; ++i)
        if ((some >> i) & 1)
            mu += medium_extinction(med, i, p, counters, has_medium(media, i, active));
#endif
    counters[C_OVER_MAJORANT] +=
        lane_ones(active & (mu > sigma_maj * (1.0f + OVER_MAJORANT_SLACK)));
    return mu;
}

/* The media whose box holds p, a bit per medium (twin in medium.py). */
static inline lint media_at(const MediumData *med, lvec3 p, lmask active) {
#if MEDIA_COUNT == 1
    return (lint)(1);
#else
    lint bits = (lint)(0);
    for (int i = 0; i < MEDIA_COUNT; ++i)
        bits = bits | select((lint)(0), (lint)(1 << i),
                             in_box(&med->m[i], to_medium(&med->m[i], p), active));
    return bits;
#endif
}

/* The counted lookup at a point of no segment: every medium whose box holds p. */
static inline __attribute__((always_inline)) lfloat extinction(const MediumData *med, lvec3 p,
                                                               lfloat sigma_maj,
                                                               lulong *counters, lmask active) {
    return extinction_in(med, media_at(med, p, active), p, sigma_maj, counters, active);
}

/* Extinction per channel relative to extinction(): 1 in grey builds (folded away). Several
 * media share it (the scene format requires it). */
static inline uspec medium_chroma(const MediumData *med) {
#if FEATURE_CHROMATIC
    return vec3(med->m[0].chroma);
#else
    return 1.0f;
#endif
}

/* Emitted radiance Le of medium i at p, RGB (twin of emitted_radiance in medium.py). */
static inline lvec3 emitted_radiance(const MediumData *med, int i, lvec3 p, lmask active) {
    const Medium *m = &med->m[i];
    global const float *table = med->table + m->table_off;
    float3 e = vec3(m->emission_rgb);
    p = to_medium(m, p);
    lfloat f = grid_lookup(med->emis + m->emis_off,
                           (int3)(m->emission_dims[0], m->emission_dims[1],
                                  m->emission_dims[2]),
                           vec3(m->bmin), vec3(m->inv_extent), p, active);
    if (m->emission_kind == EMISSION_RADIANCE) return v3(e.x * f, e.y * f, e.z * f);
    lfloat x = clamp(f * m->table_scale, 0.0f, (float)(BLACKBODY_TABLE_SIZE - 1));
    lint i0 = select((lint)(0), min(to_lint_rtz(x), BLACKBODY_TABLE_SIZE - 2), active);
    lfloat w = x - to_lfloat(i0);
    lint j = 3 * i0;
    return v3(e.x * (gather_float(table, j) * (1.0f - w) + gather_float(table, j + 3) * w),
              e.y * (gather_float(table, j + 1) * (1.0f - w) + gather_float(table, j + 4) * w),
              e.z * (gather_float(table, j + 2) * (1.0f - w) + gather_float(table, j + 5) * w));
}

/* The cell, of n along this axis, that coordinate q of the medium's space falls in. */
static inline lint majorant_cell(lfloat q, float bmin, float inv_extent, int n) {
    return clamp(to_lint(floor((q - bmin) * inv_extent * (float)n)), 0, n - 1);
}

/* The majorant at point p in the active lanes: the sum over the media whose box holds p of
 * their majorant there, the sigma_maj of the merged segment that covers p (twin in
 * medium.py). */
static inline lfloat majorant_at(const MediumData *med, lvec3 p, lmask active) {
    lfloat s = (lfloat)(0.0f);
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        const Medium *m = &med->m[i];
        lvec3 q = to_medium(m, p);
        lmask in = MEDIA_COUNT == 1 ? active : in_box(m, q, active);
        if (!ANY(in)) continue;
        global const float *maj = med->maj + m->maj_off;
        if (FEATURE_MAJORANT_GRID && m->majorant_kind == MAJORANT_GRID) {
            int cz = m->maj_res[0], cy = m->maj_res[1], cx = m->maj_res[2];
            lint k = (majorant_cell(q.z, m->bmin[2], m->inv_extent[2], cz) * cy +
                      majorant_cell(q.y, m->bmin[1], m->inv_extent[1], cy)) * cx +
                     majorant_cell(q.x, m->bmin[0], m->inv_extent[0], cx);
            s += select((lfloat)(0.0f), m->scale * gather_float(maj, select((lint)(0), k, in)),
                        in);
        } else if (FEATURE_MAJORANT_OCTREE && m->majorant_kind == MAJORANT_OCTREE) {
            int depth = m->octree_depth, n = 1 << depth;
            lint ix = majorant_cell(q.x, m->bmin[0], m->inv_extent[0], n);
            lint iy = majorant_cell(q.y, m->bmin[1], m->inv_extent[1], n);
            lint iz = majorant_cell(q.z, m->bmin[2], m->inv_extent[2], n);
            global const int *children = med->nodes + m->nodes_off;
            lint node = (lint)(0);
            lmask inner = in;
            for (int lv = 0; lv < depth && ANY(inner); ++lv) {
                lint first = gather_int(children, node);
                inner = inner & (first != 0);
                int k = depth - 1 - lv;
                node = select(node, first + (((ix >> k) & 1) | (((iy >> k) & 1) << 1) |
                                             (((iz >> k) & 1) << 2)),
                              inner);
            }
            s += select((lfloat)(0.0f), m->scale * gather_float(maj, node), in);
        } else {
            s += select((lfloat)(0.0f), (lfloat)(m->sigma_maj), in);
        }
    }
    return s;
}

/* True if some medium emits. */
static inline int media_emit(const MediumData *med) {
    int any = 0;
    for (int i = 0; i < MEDIA_COUNT; ++i) any = any || med->m[i].emission_kind != EMISSION_NONE;
    return any;
}

/* Index of the medium a real collision at p chose, by its share of the extinction there
 * (twin of medium_pick in medium.py): medium i with probability mu_i / sum mu. Lanes whose
 * point lies in one box take that medium without a lookup (in none, by rounding: medium 0);
 * the others look up every medium there (counted) and, where two or more have extinction,
 * draw a uniform from rng. */
static inline lint medium_pick(const MediumData *med, lvec3 p, Rng *rng, lulong *counters,
                               lmask active) {
#if MEDIA_COUNT == 1
    return (lint)(0);
#else
    /* A point in one box alone: that medium, without a lookup. */
    lint bits = media_at(med, p, active), only = (lint)(0);
    for (int i = 0; i < MEDIA_COUNT; ++i)
        only = select(only, (lint)(i), has_medium(bits, i, active));
    active = active & (popcount(bits) >= 2);
    if (!ANY(active)) return only;
    lfloat mu[MEDIA_COUNT];
    lfloat total = (lfloat)(0.0f);
    lint present = (lint)(0);
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        lmask on = has_medium(bits, i, active);
        mu[i] = ANY(on) ? medium_extinction(med, i, p, counters, on) : (lfloat)(0.0f);
        total += mu[i];
        present = present + ((mu[i] > 0.0f) & 1);
    }
    lmask draw = active & (present >= 2);
    lfloat x = select((lfloat)(0.0f), rng_next(rng, draw), draw) * total;
    lint pick = (lint)(-1), last = (lint)(0); /* last: the last medium present */
    lfloat acc = (lfloat)(0.0f);
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        acc += mu[i];
        lmask here = mu[i] > 0.0f;
        last = select(last, (lint)(i), here);
        pick = select(pick, (lint)(i), (pick < 0) & here & (x < acc));
    }
    /* x = total by rounding: the last present */
    return select(only, select(last, pick, pick >= 0), active);
#endif
}

/* The points of a comb, ceil(x) and at least 1, for x points asked (twin in medium.py). */
static inline lint comb_count(lfloat x) {
    return max(1, to_lint(ceil(fmin(x, COMB_COUNT_LIMIT))));
}

/* n lookups per lane (n may differ between lanes). */
static inline lfloat optical_depth_comb(const MediumData *med, lvec3 o, lvec3 d, lfloat t0,
                                        lfloat L, lint n, lfloat u, lfloat sigma_maj,
                                        lulong *counters, lmask active) {
    lfloat h = L / to_lfloat(n);
    lfloat s = (lfloat)(0.0f);
    for (int j = 0; ANY(active & (j < n)); ++j) {
        lmask on = active & (j < n);
        s += select((lfloat)(0.0f),
                    extinction(med, madd3(o, d, t0 + ((float)j + u) * h), sigma_maj, counters, on),
                    on);
    }
    return s * h;
}

/* The lanes of `active` whose segment is degenerate (see medium.py); counts the capped. */
static inline lmask segment_degenerate(lfloat L, lfloat mbar, lulong *counters, int max_steps,
                                       int min_steps, lmask active) {
    lmask empty = !(L > 0.0f) || !(mbar > 0.0f);
    if (max_steps >= min_steps) return active & empty;
    counters[C_CAPPED] += lane_ones(active & !empty);
    return active;
}

/* Twin of record_segment in medium.py, which describes the record; lane by lane, each into
 * its pixel's record. A build without FEATURE_RECORD compiles it to nothing, so a normal
 * render pays nothing for it. */
static inline void record_segment(const MediumData *med, lvec3 o, lvec3 d, lfloat t0, lfloat t1,
                                  int kind, lmask active) {
    if (!FEATURE_RECORD || med->rec == 0) return;
    for (int l = 0; l < LANES; ++l) {
        int pix = lane_int(med->rec_pixel, l);
        if (!lane_on(active, l) || pix < 0) continue;
        global float *rec = med->rec + (size_t)pix * (med->rec_capacity + 1) * RECORD_COLUMNS;
        int n = convert_int_rtz(rec[0]);
        if ((float)n >= rec[1]) continue;
        global float *row = rec + (n + 1) * RECORD_COLUMNS;
        vstore3(lane_vec3(o, l), 0, row);
        vstore3(lane_vec3(d, l), 1, row);
        row[6] = lane_float(t0, l);
        row[7] = lane_float(t1, l);
        row[8] = (float)kind;
        rec[0] = (float)(n + 1);
    }
}

/* A majorant segment: [t_min, t_max] with its extinction's bounds, and the media whose own
 * segments cover it (a bit per medium; one medium: 1), the only ones its lookups read. */
typedef struct {
    lfloat t_min, t_max, sigma_maj, sigma_min;
    lint media;
} Segment;

/* One medium's walk over its majorant segments. */
typedef struct {
    Dda dda;
    OctreeWalk oct;
    lfloat t0, t1;
    lmask done;
} MediumIter;

/* Starts medium i's walk of o + t d over [t0, t1]. With several media the segment is first
 * clipped to medium i's box (one medium's rays were clipped by enter_media). */
static inline void medium_iter_init(MediumIter *it, const MediumData *med, int i, lvec3 o,
                                    lvec3 d, lfloat t0, lfloat t1, lmask active) {
    const Medium *m = &med->m[i];
    o = to_medium(m, o);
    d = to_medium_dir(m, d);
    if (MEDIA_COUNT > 1) {
        lfloat tx;
        lfloat te = ray_box(o, d, vec3(m->bmin), vec3(m->bmax), &tx);
        t0 = fmax(t0, te);
        t1 = fmin(t1, tx);
    }
    it->done = select(it->done, !(t1 > t0), active);
    it->t0 = select(it->t0, t0, active);
    it->t1 = select(it->t1, t1, active);
    /* (several media: a medium no lane's ray crosses needs no walk) */
    if (MEDIA_COUNT > 1 && !ANY(active & (t1 > t0))) return;
    if (FEATURE_MAJORANT_GRID && m->majorant_kind == MAJORANT_GRID)
        dda_init(&it->dda, o, d, t0, t1, vec3(m->bmin), vec3(m->bmax),
                 (int3)(m->maj_res[0], m->maj_res[1], m->maj_res[2]), active);
    else if (FEATURE_MAJORANT_OCTREE && m->majorant_kind == MAJORANT_OCTREE)
        octree_init(&it->oct, o, d, t0, t1, vec3(m->bmin), vec3(m->bmax), m->octree_depth,
                    active);
}

/* Returns the lanes of `active` that got a segment of medium i (0 where its walk is over)
 * and writes their next non-empty segment. The grid's cells and the octree's leaves run
 * one loop: each walk yields a piece and its index into maj and mnr; a lane skips empty
 * pieces while the others wait for it. */
static inline lmask medium_iter_next(MediumIter *it, const MediumData *med, int i,
                                     Segment *seg, lmask active) {
    const Medium *m = &med->m[i];
    int grid = FEATURE_MAJORANT_GRID && m->majorant_kind == MAJORANT_GRID;
    int octree = FEATURE_MAJORANT_OCTREE && m->majorant_kind == MAJORANT_OCTREE;
    if (grid || octree) {
        global const float *maj = med->maj + m->maj_off, *mnr = med->mnr + m->maj_off;
        int3 res = (int3)(m->maj_res[0], m->maj_res[1], m->maj_res[2]);
        lmask found = (lmask)(0), searching = active;
        while (ANY(searching)) {
            lfloat ta, tb;
            lint k = (lint)(0);
            lmask got;
            if (grid) {
                lint3 cell;
                got = dda_next(&it->dda, &ta, &tb, &cell, searching, res);
                k = dda_cell_index(cell, res);
            } else {
                got = octree_next(&it->oct, med->nodes + m->nodes_off, vec3(m->bmin),
                                  vec3(m->bmax), m->octree_depth, &ta, &tb, &k, searching);
            }
            k = select((lint)(0), k, got);
            lfloat s_maj = m->scale * gather_float(maj, k);
            lmask hit = got & (s_maj > 0.0f) & (tb > ta);
            seg->t_min = select(seg->t_min, ta, hit);
            seg->t_max = select(seg->t_max, tb, hit);
            seg->sigma_maj = select(seg->sigma_maj, s_maj, hit);
            seg->sigma_min = select(seg->sigma_min, m->scale * gather_float(mnr, k), hit);
            found = found | hit;
            searching = got & !hit;
        }
        return found;
    }
    lmask go = active & !it->done;
    it->done = it->done | active;
    if (!(m->sigma_maj > 0.0f)) return (lmask)(0);
    seg->t_min = select(seg->t_min, it->t0, go);
    seg->t_max = select(seg->t_max, it->t1, go);
    seg->sigma_maj = select(seg->sigma_maj, (lfloat)(m->sigma_maj), go);
    seg->sigma_min = select(seg->sigma_min, (lfloat)(m->sigma_min), go);
    return go;
}

#if MEDIA_COUNT == 1
typedef MediumIter MajorantIter;

static inline void majorant_iter_init_near(MajorantIter *it, const MediumData *med, lvec3 o,
                                           lvec3 d, lfloat t0, lfloat t1, lint near,
                                           lmask active) {
    medium_iter_init(it, med, 0, o, d, t0, t1, active);
}

static inline lmask majorant_next(MajorantIter *it, const MediumData *med, Segment *seg,
                                  lmask active) {
    seg->media = (lint)(1);
    return medium_iter_next(it, med, 0, seg, active);
}
#else
/* The scene's walk: each medium's walk and its pending segment (has), merged (twin of
 * majorant_next in medium.py, which describes the merge). */
typedef struct {
    MediumIter one[MEDIA_COUNT];
    Segment cur[MEDIA_COUNT];
    lmask has[MEDIA_COUNT];
    lint open; /* the media whose walk may still yield a segment: a bit each */
    lfloat t; /* where the merged segments have reached */
} MajorantIter;

/* near: media_near of the segment, or a superset (a medium outside it starts no walk). */
static inline void majorant_iter_init_near(MajorantIter *it, const MediumData *med, lvec3 o,
                                           lvec3 d, lfloat t0, lfloat t1, lint near,
                                           lmask active) {
    it->open = select(it->open, near, active);
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        it->has[i] = it->has[i] & !active;
        /* a medium near no lane's ray: its walk is over before it starts */
        if (ANY(has_medium(near, i, active)))
            medium_iter_init(&it->one[i], med, i, o, d, t0, t1, active);
        else
            it->one[i].done = it->one[i].done | active;
    }
    it->t = select(it->t, t0, active);
}

/* The next merged segment: from the nearest point at or after t where some medium has a
 * segment, to the nearest point where one begins or ends; its bounds are the sums over the
 * media whose segment covers it. */
static inline lmask majorant_next(MajorantIter *it, const MediumData *med, Segment *seg,
                                  lmask active) {
    lfloat t = it->t;
    lfloat start = (lfloat)(FLT_MAX);
    /* The media open in some lane asked: the others have no segment pending and their walk
     * is over (most media, when a scene has many apart), and cost one test each. */
    int some = lane_or(it->open, active);
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        if (!((some >> i) & 1)) continue;
        /* A medium whose segment the merge has passed takes its next one, unless its walk
         * is over (done: no segment, or none left). */
        lmask passed = active & !(it->has[i] & (it->cur[i].t_max > t));
        it->has[i] = it->has[i] & !passed;
        lmask need = passed & !it->one[i].done;
        if (ANY(need)) {
            Segment s = {0};
            lmask got = medium_iter_next(&it->one[i], med, i, &s, need);
            it->one[i].done = it->one[i].done | (need & !got);
            it->cur[i].t_min = select(it->cur[i].t_min, s.t_min, got);
            it->cur[i].t_max = select(it->cur[i].t_max, s.t_max, got);
            it->cur[i].sigma_maj = select(it->cur[i].sigma_maj, s.sigma_maj, got);
            it->cur[i].sigma_min = select(it->cur[i].sigma_min, s.sigma_min, got);
            it->has[i] = select(it->has[i], got, need);
        }
        it->open = select(it->open, it->open & (lint)(~(1 << i)),
                          active & !it->has[i] & it->one[i].done);
        start = select(start, fmin(start, fmax(it->cur[i].t_min, t)), active & it->has[i]);
    }
    lmask found = active & (start < FLT_MAX);
    lfloat end = (lfloat)(FLT_MAX), s_maj = (lfloat)(0.0f), s_min = (lfloat)(0.0f);
    lint media = (lint)(0);
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        if (!((some >> i) & 1)) continue;
        lmask h = found & it->has[i];
        lmask covers = h & (it->cur[i].t_min <= start);
        end = select(end, fmin(end, select(it->cur[i].t_min, it->cur[i].t_max, covers)), h);
        s_maj += select((lfloat)(0.0f), it->cur[i].sigma_maj, covers);
        s_min += select((lfloat)(0.0f), it->cur[i].sigma_min, covers);
        media = media | select((lint)(0), (lint)(1 << i), covers);
    }
    seg->media = select(seg->media, media, found);
    seg->t_min = select(seg->t_min, start, found);
    seg->t_max = select(seg->t_max, end, found);
    seg->sigma_maj = select(seg->sigma_maj, s_maj, found);
    seg->sigma_min = select(seg->sigma_min, s_min, found);
    it->t = select(it->t, end, found);
    return found;
}
#endif

/* Starts the walk of o + t d over [t0, t1] through the media (twin in medium.py). */
static inline void majorant_iter_init(MajorantIter *it, const MediumData *med, lvec3 o, lvec3 d,
                                      lfloat t0, lfloat t1, lmask active) {
    majorant_iter_init_near(it, med, o, d, t0, t1, media_near(med, o, d, t0, t1, active),
                            active);
}

#endif
