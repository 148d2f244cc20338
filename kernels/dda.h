/* 3-D DDA over a majorant grid. Twin of volmc/reference/dda.py (conventions and robustness
 * arguments there): dda_next yields (t_enter, t_exit, cell) segments tiling [t0, t1]. */
#ifndef VOLMC_DDA_H
#define VOLMC_DDA_H

typedef struct {
    float t, t1;
    float tnext[3], dt[3];
    int i[3], step[3], n[3];
    int done;
} Dda;

/* res_zyx = (cz, cy, cx) cells tiling [bmin, bmax]; the segment is already clipped. */
static inline void dda_init(Dda *state, float3 o, float3 d, float t0, float t1, float3 bmin,
                            float3 bmax, int3 res_zyx) {
    float oa[3] = {o.x, o.y, o.z}, da[3] = {d.x, d.y, d.z};
    float lo[3] = {bmin.x, bmin.y, bmin.z}, hi[3] = {bmax.x, bmax.y, bmax.z};
    int n[3] = {res_zyx.z, res_zyx.y, res_zyx.x};
    state->t = t0;
    state->t1 = t1;
    state->done = !(t1 > t0);
    for (int a = 0; a < 3; ++a) {
        float size = (hi[a] - lo[a]) / (float)n[a];
        float p = oa[a] + t0 * da[a];
        int i = clamp((int)floor((p - lo[a]) / size), 0, n[a] - 1);
        state->i[a] = i;
        state->n[a] = n[a];
        if (da[a] > 0.0f) {
            state->step[a] = 1;
            state->tnext[a] = (lo[a] + (float)(i + 1) * size - oa[a]) / da[a];
            state->dt[a] = size / da[a];
        } else if (da[a] < 0.0f) {
            state->step[a] = -1;
            state->tnext[a] = (lo[a] + (float)i * size - oa[a]) / da[a];
            state->dt[a] = -size / da[a];
        } else {
            state->step[a] = 0;
            /* FLT_MAX: finite-math-only builds may fold infinities (NO_LIMIT, guards.h). */
            state->tnext[a] = FLT_MAX;
            state->dt[a] = FLT_MAX;
        }
    }
}

/* Returns 0 when the walk is over; else writes the segment and its cell (ix, iy, iz). */
static inline int dda_next(Dda *state, float *t_enter, float *t_exit, int3 *cell) {
    if (state->done) return 0;
    int a = 0;
    if (state->tnext[1] < state->tnext[a]) a = 1;
    if (state->tnext[2] < state->tnext[a]) a = 2;
    *t_enter = state->t;
    float te = fmin(fmax(state->tnext[a], state->t), state->t1);
    *cell = (int3)(state->i[0], state->i[1], state->i[2]);
    if (te >= state->t1) {
        state->done = 1;
    } else {
        int i = state->i[a] + state->step[a];
        if (i < 0 || i >= state->n[a]) {
            state->done = 1;
            te = state->t1;
        } else {
            state->i[a] = i;
            state->tnext[a] += state->dt[a];
        }
    }
    state->t = te;
    *t_exit = te;
    return 1;
}

/* Flat index of a cell (ix, iy, iz) in a [cz][cy][cx] array. */
static inline int dda_cell_index(int3 cell, int3 res_zyx) {
    return (cell.z * res_zyx.y + cell.y) * res_zyx.z + cell.x;
}

#endif
