/* The medium: what is here (density, extinction) and what bounds it along a ray (majorant
 * segments). Twin of volmc/reference/medium.py, where the density sources, the segment
 * convention and the guards are described. The record type Medium is generated from
 * volmc/params.py (MEDIUM_FIELDS) into params.h. The medium is the same for every lane;
 * points, rays and their segments are per lane. */
#ifndef VOLMC_MEDIUM_H
#define VOLMC_MEDIUM_H

#include "params.h"
#include "features.h"
#include "lanes.h"
#include "grid.h"
#include "dda.h"
#include "octree.h"
#include "spectrum.h"

/* A medium record with the arrays it points to: the density grid [nz][ny][nx], the
 * majorant grid's per-cell density maxima and minima [cz][cy][cx] (an octree's: per node),
 * the emission field grid [nz][ny][nx], the blackbody table [BLACKBODY_TABLE_SIZE][3], a
 * brick grid's index table [bz][by][bx] and pool [n_slots][8][8][8] (grid.h), and an
 * octree's first-child indices [n_nodes] (octree.h); and the segment record of the whole
 * launch, [pixels][K + 1][RECORD_COLUMNS] (record_segment; 0 when not recording), with
 * each lane's pixel (rec_pixel, -1: none). */
typedef struct {
    Medium m; /* a copy: the compiler keeps its fields in registers */
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

static inline float3 vec3(const float v[3]) { return (float3)(v[0], v[1], v[2]); }

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

static inline lfloat medium_density(const MediumData *med, lvec3 p, lmask active) {
    const Medium *m = &med->m;
    p = to_medium(m, p);
    int kind = m->density_kind;
    if (kind == DENSITY_GRID)
        return grid_lookup(med->grid, (int3)(m->dims[0], m->dims[1], m->dims[2]), vec3(m->bmin),
                           vec3(m->inv_extent), p, active);
    if (kind == DENSITY_BRICKS)
        return sparse_lookup(med->bricks, med->pool, (int3)(m->dims[0], m->dims[1], m->dims[2]),
                             vec3(m->bmin), vec3(m->inv_extent), p, active);
    if (!FEATURE_PROFILES || kind == DENSITY_CONSTANT) return (lfloat)(m->density);
    return profile_density(kind, m->profile, p.x);
}

/* The counted lookup, in the active lanes (the others' results are not to be used). Always
 * inlined, as rng_next is: PoCL's inliner kept both out of line, and inlining them measured
 * 1.14x and 1.12x samples/s at W = 1 and 16 on an fbm cloud (1.06x and 1.02x on the default
 * cloud). */
static inline __attribute__((always_inline)) lfloat extinction(const MediumData *med, lvec3 p,
                                                               lfloat sigma_maj,
                                                               lulong *counters, lmask active) {
    lfloat mu = med->m.scale * medium_density(med, p, active);
    counters[C_LOOKUPS] += lane_ones(active);
    counters[C_OVER_MAJORANT] += lane_ones(active & (mu > sigma_maj));
    return mu;
}

/* Extinction per channel relative to extinction(): 1 in grey builds (folded away). */
static inline uspec medium_chroma(const MediumData *med) {
#if FEATURE_CHROMATIC
    return vec3(med->m.chroma);
#else
    return 1.0f;
#endif
}

/* Emitted radiance Le at p, RGB (twin of emitted_radiance in medium.py). */
static inline lvec3 emitted_radiance(const MediumData *med, lvec3 p, lmask active) {
    const Medium *m = &med->m;
    float3 e = vec3(m->emission_rgb);
    p = to_medium(m, p);
    lfloat f = grid_lookup(med->emis, (int3)(m->emission_dims[0], m->emission_dims[1],
                                             m->emission_dims[2]),
                           vec3(m->bmin), vec3(m->inv_extent), p, active);
    if (m->emission_kind == EMISSION_RADIANCE) return v3(e.x * f, e.y * f, e.z * f);
    lfloat x = clamp(f * m->table_scale, 0.0f, (float)(BLACKBODY_TABLE_SIZE - 1));
    lint i0 = select((lint)(0), min(to_lint_rtz(x), BLACKBODY_TABLE_SIZE - 2), active);
    lfloat w = x - to_lfloat(i0);
    lint j = 3 * i0;
    return v3(e.x * (gather_float(med->table, j) * (1.0f - w) + gather_float(med->table, j + 3) * w),
              e.y * (gather_float(med->table, j + 1) * (1.0f - w) +
                     gather_float(med->table, j + 4) * w),
              e.z * (gather_float(med->table, j + 2) * (1.0f - w) +
                     gather_float(med->table, j + 5) * w));
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

typedef struct {
    lfloat t_min, t_max, sigma_maj, sigma_min;
} Segment;

typedef struct {
    Dda dda;
    OctreeWalk oct;
    lfloat t0, t1;
    lmask done;
} MajorantIter;

static inline void majorant_iter_init(MajorantIter *it, const MediumData *med, lvec3 o, lvec3 d,
                                      lfloat t0, lfloat t1, lmask active) {
    const Medium *m = &med->m;
    o = to_medium(m, o);
    d = to_medium_dir(m, d);
    it->done = select(it->done, !(t1 > t0), active);
    it->t0 = select(it->t0, t0, active);
    it->t1 = select(it->t1, t1, active);
    if (FEATURE_MAJORANT_GRID && m->majorant_kind == MAJORANT_GRID)
        dda_init(&it->dda, o, d, t0, t1, vec3(m->bmin), vec3(m->bmax),
                 (int3)(m->maj_res[0], m->maj_res[1], m->maj_res[2]), active);
    else if (FEATURE_MAJORANT_OCTREE && m->majorant_kind == MAJORANT_OCTREE)
        octree_init(&it->oct, o, d, t0, t1, vec3(m->bmin), vec3(m->bmax), m->octree_depth,
                    active);
}

/* Returns the lanes of `active` that got a segment (0 where the walk is over) and writes
 * their next non-empty segment. The grid's cells and the octree's leaves run one loop: each
 * walk yields a piece and its index into maj and mnr; a lane skips empty pieces while the
 * others wait for it. */
static inline lmask majorant_next(MajorantIter *it, const MediumData *med, Segment *seg,
                                  lmask active) {
    const Medium *m = &med->m;
    int grid = FEATURE_MAJORANT_GRID && m->majorant_kind == MAJORANT_GRID;
    int octree = FEATURE_MAJORANT_OCTREE && m->majorant_kind == MAJORANT_OCTREE;
    if (grid || octree) {
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
                got = octree_next(&it->oct, med->nodes, vec3(m->bmin), vec3(m->bmax),
                                  m->octree_depth, &ta, &tb, &k, searching);
            }
            k = select((lint)(0), k, got);
            lfloat s_maj = m->scale * gather_float(med->maj, k);
            lmask hit = got & (s_maj > 0.0f) & (tb > ta);
            seg->t_min = select(seg->t_min, ta, hit);
            seg->t_max = select(seg->t_max, tb, hit);
            seg->sigma_maj = select(seg->sigma_maj, s_maj, hit);
            seg->sigma_min = select(seg->sigma_min, m->scale * gather_float(med->mnr, k), hit);
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

#endif
