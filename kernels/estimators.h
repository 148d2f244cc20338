/* Transmittance estimators on a common interface. Twin of volmc/reference/estimators.py
 * (formulas, parameters and sources are documented there): same names, same arguments. */
#ifndef VOLMC_ESTIMATORS_H
#define VOLMC_ESTIMATORS_H

#include "rng.h"
#include "extinction.h"

#define EST_ARGS global const float *med, global const float *grid, int3 dims, float3 o, \
    float3 d, float t0, float t1, float mbar, float mu_c, Rng *rng, ulong *counters, int max_steps

inline float transmittance_analytic(EST_ARGS) {
    return exp(-mbar * fmax(t1 - t0, 0.0f));
}

inline float transmittance_track_length(EST_ARGS) {
    if (mbar <= 0.0f) return 1.0f;
    float inv = 1.0f / mbar;
    float t = t0;
    for (int i = 0; i < max_steps; ++i) {
        t -= log1p(-rng_next(rng)) * inv;
        if (t >= t1) return 1.0f;
        if (rng_next(rng) * mbar < lookup(med, grid, dims, o, d, t, counters, mbar)) return 0.0f;
    }
    counters[C_CAPPED] += 1;
    return 0.0f;
}

inline float transmittance_ratio_tracking(EST_ARGS) {
    if (mbar <= 0.0f) return 1.0f;
    float inv = 1.0f / mbar;
    float T = 1.0f;
    float t = t0;
    for (int i = 0; i < max_steps; ++i) {
        t -= log1p(-rng_next(rng)) * inv;
        if (t >= t1) return T;
        T *= 1.0f - lookup(med, grid, dims, o, d, t, counters, mbar) / mbar;
    }
    counters[C_CAPPED] += 1;
    return T;
}

inline float transmittance_residual_ratio(EST_ARGS) {
    float L = fmax(t1 - t0, 0.0f);
    float Tc = exp(-mu_c * L);
    float mr = mbar - mu_c;
    if (mr <= 0.0f) return Tc;
    float inv = 1.0f / mr;
    float T = Tc;
    float t = t0;
    for (int i = 0; i < max_steps; ++i) {
        t -= log1p(-rng_next(rng)) * inv;
        if (t >= t1) return T;
        T *= 1.0f - (lookup(med, grid, dims, o, d, t, counters, mbar) - mu_c) / mr;
    }
    counters[C_CAPPED] += 1;
    return T;
}

inline float transmittance_next_flight(EST_ARGS) {
    if (mbar <= 0.0f) return 1.0f;
    float inv = 1.0f / mbar;
    float w = 1.0f;
    float t = t0;
    float T = exp(-mbar * fmax(t1 - t0, 0.0f));
    for (int i = 0; i < max_steps; ++i) {
        t -= log1p(-rng_next(rng)) * inv;
        if (t >= t1) return T;
        w *= 1.0f - lookup(med, grid, dims, o, d, t, counters, mbar) / mbar;
        T += w * exp(-mbar * (t1 - t));
    }
    counters[C_CAPPED] += 1;
    return T;
}

inline float transmittance_biased_raymarch(EST_ARGS, float samples_per_mfp) {
    float L = fmax(t1 - t0, 0.0f);
    int n = max(1, (int)ceil(samples_per_mfp * mbar * L));
    if (n > max_steps) {
        counters[C_CAPPED] += 1;
        n = max_steps;
    }
    float dt = L / (float)n;
    float u = rng_next(rng);
    float tau = 0.0f;
    for (int j = 0; j < n; ++j) tau += lookup(med, grid, dims, o, d, t0 + ((float)j + u) * dt,
                                              counters, mbar);
    return exp(-tau * dt);
}

#endif
