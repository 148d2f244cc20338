/* Emission sampling: points drawn in the emitting media, and their density. Twin of
 * volmc/reference/emitters.py (which describes the uniforms and the density); the
 * distribution's cells follow the blackbody rows of each medium's table (volmc/emitters.py). */
#ifndef VOLMC_EMITTERS_H
#define VOLMC_EMITTERS_H

#include "medium.h"

/* Cell index of point q (medium space) in medium m's distribution, clamped into it. */
static inline lint emitter_cell(const Medium *m, lvec3 q) {
    int cx = m->emitter_res[0], cy = m->emitter_res[1], cz = m->emitter_res[2];
    lint ix = clamp(to_lint(floor((q.x - m->bmin[0]) * m->inv_extent[0] * (float)cx)), 0, cx - 1);
    lint iy = clamp(to_lint(floor((q.y - m->bmin[1]) * m->inv_extent[1] * (float)cy)), 0, cy - 1);
    lint iz = clamp(to_lint(floor((q.z - m->bmin[2]) * m->inv_extent[2] * (float)cz)), 0, cz - 1);
    return ix + cx * (iy + cy * iz);
}

/* Density (per unit volume of the scene frame) of sample_emitter at p, in the active lanes
 * (0 in the others). */
static inline lfloat emitter_pdf(const MediumData *med, lvec3 p, lmask active) {
    lfloat pdf = (lfloat)(0.0f);
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        const Medium *m = &med->m[i];
        if (!(m->emitter_res[0] > 0)) continue;
        lvec3 q = to_medium(m, p);
        lmask in = in_box(m, q, active);
        if (!ANY(in)) continue;
        global const float *rows = med->table + m->table_off + 3 * m->emitter_row;
        lint c = select((lint)(0), emitter_cell(m, q), in);
        pdf += select((lfloat)(0.0f), m->emitter_density * gather_float(rows, 3 * c + 2), in);
    }
    return pdf;
}

/* A point of the scene frame drawn from the emitting media from five uniforms, in the
 * active lanes; writes emitter_pdf there to *pdf (0: no medium has a distribution). */
static inline lvec3 sample_emitter(const MediumData *med, lfloat u0, lfloat u1, lfloat u2,
                                   lfloat u3, lfloat u4, lfloat *pdf, lmask active) {
    lint j = (lint)(-1);
    lfloat lo = (lfloat)(0.0f), share = (lfloat)(1.0f);
    float acc = 0.0f;
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        float P = med->m[i].emitter_prob;
        if (!(P > 0.0f)) continue;
        lmask take = (j < 0) | (u0 >= acc); /* the last medium whose range starts below u0 */
        j = select(j, (lint)(i), take);
        lo = select(lo, (lfloat)(acc), take);
        share = select(share, (lfloat)(P), take);
        acc += P;
    }
    lvec3 p = v3s(0.0f);
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        lmask here = active & (j == i);
        if (!ANY(here)) continue;
        const Medium *m = &med->m[i];
        global const float *rows = med->table + m->table_off + 3 * m->emitter_row;
        int cx = m->emitter_res[0], cy = m->emitter_res[1], cz = m->emitter_res[2];
        int n = cx * cy * cz;
        lfloat v = clamp((u0 - lo) / share, 0.0f, 1.0f);
        lint c = select((lint)(0), min(to_lint_rtz(v * (float)n), n - 1), here);
        lmask other = here & !(u1 < gather_float(rows, 3 * c));
        c = select(c, to_lint_rtz(gather_float(rows, 3 * c + 1)), other);
        lint ix = c % cx, iy = (c / cx) % cy, iz = c / (cx * cy);
        lvec3 q = v3(m->bmin[0] + (to_lfloat(ix) + u2) / ((float)cx * m->inv_extent[0]),
                     m->bmin[1] + (to_lfloat(iy) + u3) / ((float)cy * m->inv_extent[1]),
                     m->bmin[2] + (to_lfloat(iz) + u4) / ((float)cz * m->inv_extent[2]));
        const float *x = m->emitter_to_scene;
        p = sel3(p, v3(x[0] * q.x + x[1] * q.y + x[2] * q.z + x[3],
                       x[4] * q.x + x[5] * q.y + x[6] * q.z + x[7],
                       x[8] * q.x + x[9] * q.y + x[10] * q.z + x[11]),
                 here);
    }
    lmask found = active & (j >= 0);
    *pdf = select((lfloat)(0.0f), emitter_pdf(med, p, found), found);
    return p;
}

#endif
