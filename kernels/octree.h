/* Walk of a ray through the leaves of an octree of majorants. Twin of
 * volmc/reference/octree.py (layout, conventions and robustness arguments there):
 * octree_next yields (t_enter, t_exit, leaf) segments tiling [t0, t1]. One walk per lane;
 * the descent to a leaf runs while any lane still has an inner node. */
#ifndef VOLMC_OCTREE_H
#define VOLMC_OCTREE_H

#include "lanes.h"

typedef struct {
    lfloat o[3], d[3];
    lfloat t, t1;
    lint i[3]; /* finest-level cell (x, y, z) of the current point */
    lmask done;
} OctreeWalk;

/* The segment is already clipped to the box [bmin, bmax]; depth: the octree's depth D.
 * Starts the walk of the active lanes. */
static inline void octree_init(OctreeWalk *state, lvec3 o, lvec3 d, lfloat t0, lfloat t1,
                               float3 bmin, float3 bmax, int depth, lmask active) {
    lfloat oa[3] = {o.x, o.y, o.z}, da[3] = {d.x, d.y, d.z};
    float lo[3] = {bmin.x, bmin.y, bmin.z}, hi[3] = {bmax.x, bmax.y, bmax.z};
    int n = 1 << depth;
    state->t = select(state->t, t0, active);
    state->t1 = select(state->t1, t1, active);
    state->done = select(state->done, !(t1 > t0), active);
    LANE_UNROLL for (int a = 0; a < 3; ++a) {
        state->o[a] = select(state->o[a], oa[a], active);
        state->d[a] = select(state->d[a], da[a], active);
        float size = (hi[a] - lo[a]) / (float)n;
        lfloat x = clamp((oa[a] + t0 * da[a] - lo[a]) / size, 0.0f, (float)(n - 1));
        state->i[a] = select(state->i[a], to_lint(floor(x)), active);
    }
}

/* Returns the lanes of `active` that got a segment (0 where the walk is over); writes
 * their segments and their leaves' node indices. */
static inline lmask octree_next(OctreeWalk *state, global const int *children, float3 bmin,
                                float3 bmax, int depth, lfloat *t_enter, lfloat *t_exit,
                                lint *node, lmask active) {
    lmask go = active & !state->done;
    float lo3[3] = {bmin.x, bmin.y, bmin.z}, hi3[3] = {bmax.x, bmax.y, bmax.z};
    lint k = (lint)(0), level = (lint)(0);
    lmask inner = go;
    for (int lv = 0; lv < depth && ANY(inner); ++lv) {
        lint first = gather_int(children, k);
        inner = inner & (first != 0);
        int s = depth - 1 - lv;
        lint octant = ((state->i[0] >> s) & 1) | (((state->i[1] >> s) & 1) << 1) |
                      (((state->i[2] >> s) & 1) << 2);
        k = select(k, first + octant, inner);
        level = level + (inner & 1);
    }
    lint span_log = depth - level;
    lint span = (lint)(1) << span_log;
    int n = 1 << depth;
    lmask exit_axis[3];
    lfloat t_face = (lfloat)(FLT_MAX); /* finite-math-only builds may fold infinities */
    LANE_UNROLL for (int a = 0; a < 3; ++a) {
        lfloat da = state->d[a];
        lint lo = (state->i[a] >> span_log) << span_log;
        lint face = select(lo, lo + span, da > 0.0f);
        float size = (hi3[a] - lo3[a]) / (float)n;
        lfloat tf = (lo3[a] + to_lfloat(face) * size - state->o[a]) / da;
        exit_axis[a] = da != 0.0f && tf < t_face;
        t_face = select(t_face, tf, exit_axis[a]);
    }
    /* The last axis that lowered t_face is the exit axis (strict <: the lowest on ties). */
    exit_axis[0] = exit_axis[0] & !exit_axis[1] & !exit_axis[2];
    exit_axis[1] = exit_axis[1] & !exit_axis[2];
    lmask none = !exit_axis[0] & !exit_axis[1] & !exit_axis[2];
    exit_axis[0] = exit_axis[0] | none; /* a_exit = 0 when no face is crossed */
    *t_enter = state->t;
    lfloat te = fmin(fmax(t_face, state->t), state->t1);
    lmask end = go & (te >= state->t1);
    lmask step = go & !end;
    lint i = (lint)(0);
    LANE_UNROLL for (int a = 0; a < 3; ++a) {
        lint lo = (state->i[a] >> span_log) << span_log;
        i = select(i, select(lo - 1, lo + span, state->d[a] > 0.0f), exit_axis[a]);
    }
    /* Rounding left the box early: the last leaf ends the segment (octree.py). */
    lmask out = step & (i < 0 || i >= n);
    lmask move = step & !out;
    LANE_UNROLL for (int a = 0; a < 3; ++a) {
        lfloat db = state->d[a];
        lint cur = state->i[a];
        lint lb = (cur >> span_log) << span_log;
        float size = (hi3[a] - lo3[a]) / (float)n;
        lfloat x = (state->o[a] + te * db - lo3[a]) / size;
        lint j = to_lint(floor(clamp(x, to_lfloat(lb), to_lfloat(lb + span - 1))));
        j = select(min(j, cur), max(j, cur), db > 0.0f);
        lmask other = move & !exit_axis[a] & (db != 0.0f);
        state->i[a] = select(select(state->i[a], j, other), i, move & exit_axis[a]);
    }
    state->done = state->done | end | out;
    te = select(te, state->t1, out);
    state->t = select(state->t, te, go);
    *t_exit = te;
    *node = k;
    return go;
}

#endif
