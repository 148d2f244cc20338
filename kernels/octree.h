/* Walk of a ray through the leaves of an octree of majorants. Twin of
 * volmc/reference/octree.py (layout, conventions and robustness arguments there):
 * octree_next yields (t_enter, t_exit, leaf) segments tiling [t0, t1]. */
#ifndef VOLMC_OCTREE_H
#define VOLMC_OCTREE_H

typedef struct {
    float o[3], d[3];
    float t, t1;
    int i[3]; /* finest-level cell (x, y, z) of the current point */
    int done;
} OctreeWalk;

/* The segment is already clipped to the box [bmin, bmax]; depth: the octree's depth D. */
static inline void octree_init(OctreeWalk *state, float3 o, float3 d, float t0, float t1,
                               float3 bmin, float3 bmax, int depth) {
    float oa[3] = {o.x, o.y, o.z}, da[3] = {d.x, d.y, d.z};
    float lo[3] = {bmin.x, bmin.y, bmin.z}, hi[3] = {bmax.x, bmax.y, bmax.z};
    int n = 1 << depth;
    state->t = t0;
    state->t1 = t1;
    state->done = !(t1 > t0);
    for (int a = 0; a < 3; ++a) {
        state->o[a] = oa[a];
        state->d[a] = da[a];
        float size = (hi[a] - lo[a]) / (float)n;
        float x = clamp((oa[a] + t0 * da[a] - lo[a]) / size, 0.0f, (float)(n - 1));
        state->i[a] = (int)floor(x);
    }
}

/* Returns 0 when the walk is over; else writes the segment and its leaf's node index. */
static inline int octree_next(OctreeWalk *state, global const int *children, float3 bmin,
                              float3 bmax, int depth, float *t_enter, float *t_exit, int *node) {
    if (state->done) return 0;
    float lo3[3] = {bmin.x, bmin.y, bmin.z}, hi3[3] = {bmax.x, bmax.y, bmax.z};
    int k = 0, level = 0;
    while (level < depth && children[k] != 0) {
        int s = depth - 1 - level;
        k = children[k] + (((state->i[0] >> s) & 1) | (((state->i[1] >> s) & 1) << 1) |
                           (((state->i[2] >> s) & 1) << 2));
        ++level;
    }
    int span_log = depth - level;
    int span = 1 << span_log, n = 1 << depth;
    int a_exit = 0;
    float t_face = FLT_MAX; /* finite-math-only builds may fold infinities (guards.h) */
    for (int a = 0; a < 3; ++a) {
        float da = state->d[a];
        if (da != 0.0f) {
            int lo = (state->i[a] >> span_log) << span_log;
            int face = da > 0.0f ? lo + span : lo;
            float size = (hi3[a] - lo3[a]) / (float)n;
            float tf = (lo3[a] + (float)face * size - state->o[a]) / da;
            if (tf < t_face) {
                t_face = tf;
                a_exit = a;
            }
        }
    }
    *t_enter = state->t;
    float te = fmin(fmax(t_face, state->t), state->t1);
    if (te >= state->t1) {
        state->done = 1;
    } else {
        float da = state->d[a_exit];
        int lo = (state->i[a_exit] >> span_log) << span_log;
        int i = da > 0.0f ? lo + span : lo - 1;
        if (i < 0 || i >= n) {
            state->done = 1;
            te = state->t1;
        } else {
            for (int a = 0; a < 3; ++a) {
                float db = state->d[a];
                if (a == a_exit || db == 0.0f) continue;
                int cur = state->i[a];
                int lb = (cur >> span_log) << span_log;
                float size = (hi3[a] - lo3[a]) / (float)n;
                float x = (state->o[a] + te * db - lo3[a]) / size;
                int j = (int)floor(clamp(x, (float)lb, (float)(lb + span - 1)));
                state->i[a] = db > 0.0f ? max(j, cur) : min(j, cur);
            }
            state->i[a_exit] = i;
        }
    }
    state->t = te;
    *t_exit = te;
    *node = k;
    return 1;
}

#endif
