/* The medium: what is here (density, extinction) and what bounds it along a ray (majorant
 * segments). Twin of volmc/reference/medium.py, where the density sources, the segment
 * convention and the guards are described. The record type Medium is generated from
 * volmc/params.py (MEDIUM_FIELDS) into params.h. */
#ifndef VOLMC_MEDIUM_H
#define VOLMC_MEDIUM_H

#include "params.h"
#include "features.h"
#include "grid.h"
#include "dda.h"
#include "octree.h"
#include "spectrum.h"

/* A medium record with the arrays it points to: the density grid [nz][ny][nx], the
 * majorant grid's per-cell density maxima and minima [cz][cy][cx] (an octree's: per node),
 * the emission field grid [nz][ny][nx], the blackbody table [BLACKBODY_TABLE_SIZE][3], a
 * brick grid's index table [bz][by][bx] and pool [n_slots][8][8][8] (grid.h), and an
 * octree's first-child indices [n_nodes] (octree.h), and the pixel's segment record
 * [K + 1][RECORD_COLUMNS] (record_segment; 0 when not recording). */
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
} MediumData;

static inline float3 vec3(const float v[3]) { return (float3)(v[0], v[1], v[2]); }

static inline float profile_density(int kind, const float prof[5], float x) {
    float a = prof[0], b = prof[1], c = prof[2], s = prof[3], L = prof[4];
    if (kind == DENSITY_RAMP) return a + (b - a) * x / L;
    if (kind == DENSITY_GAUSS_BUMP) {
        float y = (x - c) / s;
        return a + b * exp(-0.5f * y * y);
    }
    if (kind == DENSITY_GAUSS_HOLE) {
        float y = (x - c) / s;
        return fmax(a - b * exp(-0.5f * y * y), 0.0f);
    }
    return a * (1.0f + b * cos(TWO_PI * c * x / L + s));
}

static inline float medium_density(const MediumData *med, float3 p) {
    const Medium *m = &med->m;
    int kind = m->density_kind;
    if (kind == DENSITY_GRID)
        return grid_lookup(med->grid, (int3)(m->dims[0], m->dims[1], m->dims[2]), vec3(m->bmin),
                           vec3(m->inv_extent), p);
    if (kind == DENSITY_BRICKS)
        return sparse_lookup(med->bricks, med->pool, (int3)(m->dims[0], m->dims[1], m->dims[2]),
                             vec3(m->bmin), vec3(m->inv_extent), p);
    if (!FEATURE_PROFILES || kind == DENSITY_CONSTANT) return m->density;
    return profile_density(kind, m->profile, p.x);
}

static inline float extinction(const MediumData *med, float3 p, float sigma_maj, ulong *counters) {
    float mu = med->m.scale * medium_density(med, p);
    counters[C_LOOKUPS] += 1;
    if (mu > sigma_maj) counters[C_OVER_MAJORANT] += 1;
    return mu;
}

/* Extinction per channel relative to extinction(): 1 in grey builds (folded away). */
static inline spec medium_chroma(const MediumData *med) {
#if FEATURE_CHROMATIC
    return vec3(med->m.chroma);
#else
    return 1.0f;
#endif
}

/* Emitted radiance Le at p, RGB (twin of emitted_radiance in medium.py). */
static inline float3 emitted_radiance(const MediumData *med, float3 p) {
    const Medium *m = &med->m;
    float3 e = vec3(m->emission_rgb);
    float f = grid_lookup(med->emis, (int3)(m->emission_dims[0], m->emission_dims[1],
                                            m->emission_dims[2]),
                          vec3(m->bmin), vec3(m->inv_extent), p);
    if (m->emission_kind == EMISSION_RADIANCE) return e * f;
    float x = clamp(f * m->table_scale, 0.0f, (float)(BLACKBODY_TABLE_SIZE - 1));
    int i0 = min(convert_int_rtz(x), BLACKBODY_TABLE_SIZE - 2);
    float w = x - (float)i0;
    float3 a = vload3(i0, med->table), b = vload3(i0 + 1, med->table);
    return e * (a * (1.0f - w) + b * w);
}

static inline float optical_depth_comb(const MediumData *med, float3 o, float3 d, float t0,
                                       float L, int n, float u, float sigma_maj, ulong *counters) {
    float h = L / (float)n;
    float s = 0.0f;
    for (int j = 0; j < n; ++j)
        s += extinction(med, o + (t0 + ((float)j + u) * h) * d, sigma_maj, counters);
    return s * h;
}

static inline bool segment_degenerate(float L, float mbar, ulong *counters, int max_steps,
                                      int min_steps) {
    if (!(L > 0.0f) || !(mbar > 0.0f)) return true;
    if (max_steps < min_steps) {
        counters[C_CAPPED] += 1;
        return true;
    }
    return false;
}

/* Twin of record_segment in medium.py, which describes the record. A build without
 * FEATURE_RECORD compiles it to nothing, so a normal render pays nothing for it. */
static inline void record_segment(const MediumData *med, float3 o, float3 d, float t0, float t1,
                                  int kind) {
    if (!FEATURE_RECORD || med->rec == 0) return;
    global float *rec = med->rec;
    int n = convert_int_rtz(rec[0]);
    if ((float)n >= rec[1]) return;
    global float *row = rec + (n + 1) * RECORD_COLUMNS;
    vstore3(o, 0, row);
    vstore3(d, 1, row);
    row[6] = t0;
    row[7] = t1;
    row[8] = (float)kind;
    rec[0] = (float)(n + 1);
}

typedef struct {
    float t_min, t_max, sigma_maj, sigma_min;
} Segment;

typedef struct {
    Dda dda;
    OctreeWalk oct;
    float t0, t1;
    int done;
} MajorantIter;

static inline void majorant_iter_init(MajorantIter *it, const MediumData *med, float3 o, float3 d,
                                      float t0, float t1) {
    const Medium *m = &med->m;
    it->done = !(t1 > t0);
    it->t0 = t0;
    it->t1 = t1;
    if (FEATURE_MAJORANT_GRID && m->majorant_kind == MAJORANT_GRID)
        dda_init(&it->dda, o, d, t0, t1, vec3(m->bmin), vec3(m->bmax),
                 (int3)(m->maj_res[0], m->maj_res[1], m->maj_res[2]));
    else if (FEATURE_MAJORANT_OCTREE && m->majorant_kind == MAJORANT_OCTREE)
        octree_init(&it->oct, o, d, t0, t1, vec3(m->bmin), vec3(m->bmax), m->octree_depth);
}

/* Returns 0 at the end; else writes the next non-empty segment. The grid's cells and the
 * octree's leaves run one loop: each walk yields a piece and its index into maj and mnr. */
static inline int majorant_next(MajorantIter *it, const MediumData *med, Segment *seg) {
    const Medium *m = &med->m;
    int grid = FEATURE_MAJORANT_GRID && m->majorant_kind == MAJORANT_GRID;
    int octree = FEATURE_MAJORANT_OCTREE && m->majorant_kind == MAJORANT_OCTREE;
    if (grid || octree) {
        int3 res = (int3)(m->maj_res[0], m->maj_res[1], m->maj_res[2]);
        float ta, tb;
        int3 cell;
        int k = 0;
        while (grid ? dda_next(&it->dda, &ta, &tb, &cell)
                    : octree_next(&it->oct, med->nodes, vec3(m->bmin), vec3(m->bmax),
                                  m->octree_depth, &ta, &tb, &k)) {
            if (grid) k = dda_cell_index(cell, res);
            float s_maj = m->scale * med->maj[k];
            if (s_maj > 0.0f && tb > ta) {
                seg->t_min = ta;
                seg->t_max = tb;
                seg->sigma_maj = s_maj;
                seg->sigma_min = m->scale * med->mnr[k];
                return 1;
            }
        }
        return 0;
    }
    if (it->done) return 0;
    it->done = 1;
    if (!(m->sigma_maj > 0.0f)) return 0;
    seg->t_min = it->t0;
    seg->t_max = it->t1;
    seg->sigma_maj = m->sigma_maj;
    seg->sigma_min = m->sigma_min;
    return 1;
}

#endif
