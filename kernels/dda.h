/* 3-D DDA over a majorant grid. Twin of volmc/reference/dda.py (conventions and robustness
 * arguments there): dda_next yields (t_enter, t_exit, cell) segments tiling [t0, t1]. One
 * walk per lane; the grid is the same for every lane. The axis a lane steps along is a mask
 * per axis (the scalar code's array index). */
#ifndef VOLMC_DDA_H
#define VOLMC_DDA_H

#include "lanes.h"

typedef struct {
    lfloat t, t1;
    lfloat tnext[3], dt[3];
    lint i[3], step[3];
    lmask done;
} Dda;

/* res_zyx = (cz, cy, cx) cells tiling [bmin, bmax]; the segment is already clipped. Starts
 * the walk of the active lanes. */
static inline void dda_init(Dda *state, lvec3 o, lvec3 d, lfloat t0, lfloat t1, float3 bmin,
                            float3 bmax, int3 res_zyx, lmask active) {
    lfloat oa[3] = {o.x, o.y, o.z}, da[3] = {d.x, d.y, d.z};
    float lo[3] = {bmin.x, bmin.y, bmin.z}, hi[3] = {bmax.x, bmax.y, bmax.z};
    int n[3] = {res_zyx.z, res_zyx.y, res_zyx.x};
    state->t = select(state->t, t0, active);
    state->t1 = select(state->t1, t1, active);
    state->done = select(state->done, !(t1 > t0), active);
    LANE_UNROLL for (int a = 0; a < 3; ++a) {
        float size = (hi[a] - lo[a]) / (float)n[a];
        lfloat p = oa[a] + t0 * da[a];
        lint i = clamp(to_lint(floor((p - lo[a]) / size)), 0, n[a] - 1);
        lmask up = da[a] > 0.0f, down = da[a] < 0.0f;
        lfloat face = lo[a] + to_lfloat(select(i, i + 1, up)) * size;
        state->i[a] = select(state->i[a], i, active);
        state->step[a] = select(state->step[a], select(select((lint)(0), (lint)(-1), down),
                                                       (lint)(1), up), active);
        /* FLT_MAX: finite-math-only builds may fold infinities (NO_LIMIT, guards.h). */
        state->tnext[a] = select(state->tnext[a], select((lfloat)(FLT_MAX),
                                                         (face - oa[a]) / da[a], up | down),
                                 active);
        state->dt[a] = select(state->dt[a], select((lfloat)(FLT_MAX), fabs(size / da[a]),
                                                   up | down), active);
    }
}

/* Returns the lanes of `active` that got a segment (0 where the walk is over); writes
 * their segments and cells (ix, iy, iz). res_zyx: the grid's (the reference keeps it in the
 * state; here it is the same for every lane, so it stays out of the per-lane record). */
static inline lmask dda_next(Dda *state, lfloat *t_enter, lfloat *t_exit, lint3 *cell,
                             lmask active, int3 res_zyx) {
    int na[3] = {res_zyx.z, res_zyx.y, res_zyx.x};
    lmask go = active & !state->done;
    /* The axis whose face comes first (the lowest on ties, as the scalar code). */
    lmask is1 = state->tnext[1] < state->tnext[0];
    lfloat tn = select(state->tnext[0], state->tnext[1], is1);
    lmask is2 = state->tnext[2] < tn;
    tn = select(tn, state->tnext[2], is2);
    lmask axis[3] = {!is1 & !is2, is1 & !is2, is2};
    *t_enter = state->t;
    lfloat te = fmin(fmax(tn, state->t), state->t1);
    cell->x = state->i[0];
    cell->y = state->i[1];
    cell->z = state->i[2];
    lmask end = go & (te >= state->t1);
    lmask step = go & !end;
    lint i = (lint)(0);
    lint n = (lint)(0);
    LANE_UNROLL for (int a = 0; a < 3; ++a) {
        i = select(i, state->i[a] + state->step[a], axis[a]);
        n = select(n, (lint)(na[a]), axis[a]);
    }
    /* Rounding left the grid early: the last cell ends the segment (dda.py). */
    lmask out = step & (i < 0 || i >= n);
    lmask move = step & !out;
    LANE_UNROLL for (int a = 0; a < 3; ++a) {
        state->i[a] = select(state->i[a], i, move & axis[a]);
        state->tnext[a] = select(state->tnext[a], state->tnext[a] + state->dt[a],
                                 move & axis[a]);
    }
    state->done = state->done | end | out;
    te = select(te, state->t1, out);
    state->t = select(state->t, te, go);
    *t_exit = te;
    return go;
}

/* Flat index of a cell (ix, iy, iz) in a [cz][cy][cx] array. */
static inline lint dda_cell_index(lint3 cell, int3 res_zyx) {
    return (cell.z * res_zyx.y + cell.y) * res_zyx.z + cell.x;
}

#endif
