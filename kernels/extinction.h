/* Extinction along a ray for the transmittance estimators. Twin of
 * volmc/reference/extinction.py, where the layout of the float array med is documented:
 * med[0] selects a grid (MED_GRID) or an analytic 1-D profile of the ray parameter t. */
#ifndef VOLMC_EXTINCTION_H
#define VOLMC_EXTINCTION_H

#include "params.h" /* MED_* (volmc/constants.py) */
#include "grid.h"

inline float extinction_profile(global const float *med, float t) {
    int kind = (int)med[0];
    float a = med[1], b = med[2], c = med[3], s = med[4], L = med[5];
    if (kind == MED_CONSTANT) return a;
    if (kind == MED_RAMP) return a + (b - a) * t / L;
    if (kind == MED_GAUSS_BUMP) {
        float x = (t - c) / s;
        return a + b * exp(-0.5f * x * x);
    }
    if (kind == MED_GAUSS_HOLE) {
        float x = (t - c) / s;
        return fmax(a - b * exp(-0.5f * x * x), 0.0f);
    }
    return a * (1.0f + b * cos(TWO_PI * c * t / L + s));
}

inline float extinction(global const float *med, global const float *grid, int3 dims, float3 o,
                        float3 d, float t, ulong *counters) {
    counters[C_LOOKUPS] += 1;
    if ((int)med[0] == MED_GRID)
        return med[7] * grid_lookup(grid, dims, (float3)(med[1], med[2], med[3]),
                                    (float3)(med[4], med[5], med[6]), o + t * d);
    return extinction_profile(med, t);
}

/* extinction() that also counts lookups above the majorant (a broken bound is counted). */
inline float lookup(global const float *med, global const float *grid, int3 dims, float3 o,
                    float3 d, float t, ulong *counters, float mbar) {
    float mu = extinction(med, grid, dims, o, d, t, counters);
    if (mu > mbar) counters[C_OVER_MAJORANT] += 1;
    return mu;
}

#endif
