/* Tracking through the medium: free-flight sampling (transmittance estimators: estimators.h).
 * Twin of volmc/reference/transmittance.py (conventions, counters and step caps there).
 * A ray is o + t d on [t0, t1] inside the box, extinction mu = scale * density, global
 * majorant mbar. Counters are a private ulong array indexed by the C_* constants. */
#ifndef VOLMC_TRANSMITTANCE_H
#define VOLMC_TRANSMITTANCE_H

#include "params.h" /* EVENT_* (volmc/constants.py) */
#include "rng.h"
#include "grid.h"
#include "dda.h"

inline float sigma_t_at(global const float *grid, int3 dims, float3 bmin, float3 inv_extent,
                        float scale, float3 o, float3 d, float t, ulong *counters, float mbar) {
    float mu = scale * grid_lookup(grid, dims, bmin, inv_extent, o + t * d);
    counters[C_LOOKUPS] += 1;
    if (mu > mbar) counters[C_OVER_MAJORANT] += 1;
    return mu;
}

/* Returns the event; writes the collision distance (t1 on escape) to *t_out. */
inline int free_flight_homogeneous(float sigma_t, float t0, float t1, Rng *rng, float *t_out) {
    *t_out = t1;
    if (sigma_t <= 0.0f) return EVENT_ESCAPE;
    float t = t0 - log1p(-rng_next(rng)) / sigma_t;
    if (t >= t1) return EVENT_ESCAPE;
    *t_out = t;
    return EVENT_SCATTER;
}

inline int free_flight_delta(global const float *grid, int3 dims, float3 bmin, float3 inv_extent,
                             float scale, float mbar, float3 o, float3 d, float t0, float t1,
                             Rng *rng, ulong *counters, int max_steps, float *t_out) {
    *t_out = t1;
    if (mbar <= 0.0f) return EVENT_ESCAPE;
    float inv_mbar = 1.0f / mbar;
    /* Guard "local distances": the walk starts at o' = o + t0 d and s runs from 0 (see
     * free_flight_delta in transmittance.py). */
    o = o + t0 * d;
    float L = t1 - t0, s = 0.0f;
    for (int i = 0; i < max_steps; ++i) {
        s -= log1p(-rng_next(rng)) * inv_mbar;
        if (s >= L) return EVENT_ESCAPE;
        float mu = sigma_t_at(grid, dims, bmin, inv_extent, scale, o, d, s, counters, mbar);
        if (rng_next(rng) * mbar < mu) {
            *t_out = t0 + s;
            return EVENT_SCATTER;
        }
    }
    counters[C_CAPPED] += 1;
    *t_out = t0 + s;
    return EVENT_CAPPED;
}

inline float transmittance_homogeneous(float sigma_t, float t0, float t1) {
    return exp(-sigma_t * fmax(t1 - t0, 0.0f));
}

/* Free flight over a majorant grid: delta tracking, or decomposition tracking with the cell
 * minorant as the control (use_control). Twin of free_flight_grid, where the algorithm and
 * why both make the same decisions for the same random numbers are explained. */
inline int free_flight_grid(global const float *grid, int3 dims, float3 bmin, float3 bmax,
                            float3 inv_extent, float scale, global const float *maj,
                            global const float *mnr, int use_control, int3 maj_res, float3 o,
                            float3 d, float t0, float t1, Rng *rng, ulong *counters,
                            int max_steps, float *t_out) {
    /* Guard "local distances": the walk starts at o' = o + t0 d with local distances in
     * [0, t1 - t0] (the DDA included); t0 is added back to the result. */
    *t_out = t1;
    o = o + t0 * d;
    float t_base = t0;
    Dda s;
    dda_init(&s, o, d, 0.0f, t1 - t0, bmin, bmax, maj_res);
    float budget = -log1p(-rng_next(rng));
    int steps = 0;
    float ta, tb;
    int3 cell;
    while (dda_next(&s, &ta, &tb, &cell)) {
        int k = dda_cell_index(cell, maj_res);
        float m = scale * maj[k];
        if (m <= 0.0f) continue;
        float mc = use_control ? scale * mnr[k] : 0.0f;
        float t = ta;
        while (true) {
            float step = budget / m;
            if (t + step >= tb) {
                budget -= m * (tb - t);
                break;
            }
            t += step;
            float um = rng_next(rng) * m;
            if (um < mc ||
                um < sigma_t_at(grid, dims, bmin, inv_extent, scale, o, d, t, counters, m)) {
                *t_out = t_base + t;
                return EVENT_SCATTER;
            }
            budget = -log1p(-rng_next(rng));
            if (++steps >= max_steps) {
                counters[C_CAPPED] += 1;
                *t_out = t_base + t;
                return EVENT_CAPPED;
            }
        }
    }
    return EVENT_ESCAPE;
}

#endif
