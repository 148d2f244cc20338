/* Transmittance estimators on a common interface. Twin of volmc/reference/estimators.py
 * (formulas, parameters and sources are documented there): same names, same arguments. */
#ifndef VOLMC_ESTIMATORS_H
#define VOLMC_ESTIMATORS_H

#include "params.h" /* TR_RR_THRESHOLD (volmc/constants.py) */
#include "rng.h"
#include "extinction.h"

#define EST_ARGS global const float *med, global const float *grid, int3 dims, float3 o, \
    float3 d, float t0, float t1, float mbar, float mu_c, Rng *rng, ulong *counters, int max_steps

/* Guard "transmittance roulette" (HARD_CASES 10): once a running transmittance weight |T| is
 * below TR_RR_THRESHOLD the walk goes on with probability |T| / TR_RR_THRESHOLD carrying
 * +-TR_RR_THRESHOLD (same mean: unbiased), and T == 0 ends it. Dense shadow rays then stop
 * after a few lookups instead of walking the whole majorant optical depth. Returns 0 when the
 * walk ends (T is then 0). Twin of transmittance_roulette in estimators.py. */
inline int transmittance_roulette(float *T, Rng *rng) {
    float a = fabs(*T);
    if (!(a < TR_RR_THRESHOLD)) return 1;
    if (a == 0.0f || rng_next(rng) * TR_RR_THRESHOLD >= a) {
        *T = 0.0f;
        return 0;
    }
    *T = *T > 0.0f ? TR_RR_THRESHOLD : -TR_RR_THRESHOLD;
    return 1;
}

/* Guard "local distances" (HARD_CASES 11): every tracking loop accumulates the distance s
 * from the segment start t0, never t itself, so a far ray origin (t0 = 1e5 with a majorant
 * of 1e3: t + dt == t in float32) cannot stall the walk. */

inline float transmittance_analytic(EST_ARGS) {
    return exp(-mbar * fmax(t1 - t0, 0.0f));
}

inline float transmittance_track_length(EST_ARGS) {
    if (mbar <= 0.0f) return 1.0f;
    float inv = 1.0f / mbar;
    float L = t1 - t0, s = 0.0f;
    for (int i = 0; i < max_steps; ++i) {
        s -= log1p(-rng_next(rng)) * inv;
        if (s >= L) return 1.0f;
        if (rng_next(rng) * mbar < lookup(med, grid, dims, o, d, t0 + s, counters, mbar))
            return 0.0f;
    }
    counters[C_CAPPED] += 1;
    return 0.0f;
}

inline float transmittance_residual_ratio(EST_ARGS) {
    float L = fmax(t1 - t0, 0.0f);
    float Tc = exp(-mu_c * L);
    float mr = mbar - mu_c;
    if (mr <= 0.0f) return Tc;
    float inv = 1.0f / mr;
    float T = Tc;
    float s = 0.0f;
    for (int i = 0; i < max_steps; ++i) {
        s -= log1p(-rng_next(rng)) * inv;
        if (s >= L) return T;
        T *= 1.0f - (lookup(med, grid, dims, o, d, t0 + s, counters, mbar) - mu_c) / mr;
        if (!transmittance_roulette(&T, rng)) return T;
    }
    counters[C_CAPPED] += 1;
    return T;
}

/* Ratio tracking is residual ratio tracking with a zero control: exp(-0 L) = 1 and
 * mu - 0 = mu exactly, so it is the same walk with the same lookups and estimates. Twin of
 * transmittance_ratio_tracking in estimators.py. */
inline float transmittance_ratio_tracking(EST_ARGS) {
    return transmittance_residual_ratio(med, grid, dims, o, d, t0, t1, mbar, 0.0f, rng,
                                        counters, max_steps);
}

inline float transmittance_next_flight(EST_ARGS) {
    if (mbar <= 0.0f) return 1.0f;
    float inv = 1.0f / mbar;
    float w = 1.0f;
    float L = t1 - t0, s = 0.0f;
    float T = exp(-mbar * fmax(L, 0.0f));
    for (int i = 0; i < max_steps; ++i) {
        s -= log1p(-rng_next(rng)) * inv;
        if (s >= L) return T;
        w *= 1.0f - lookup(med, grid, dims, o, d, t0 + s, counters, mbar) / mbar;
        if (!transmittance_roulette(&w, rng)) return T;
        T += w * exp(-mbar * (L - s));
    }
    counters[C_CAPPED] += 1;
    return T;
}

inline float transmittance_biased_raymarch(EST_ARGS, float samples_per_mfp) {
    float L = fmax(t1 - t0, 0.0f);
    if (mbar <= 0.0f || L <= 0.0f) return 1.0f;
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
