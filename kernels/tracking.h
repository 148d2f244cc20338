/* The tracking loop, written once: tentative collisions over the medium's majorant segments
 * and what each technique (TRACK_*) does at them. Twin of volmc/reference/tracking.py, where
 * the techniques, the carried optical-depth budget, the exact treatment of homogeneous
 * segments and the guards (local distances, step cap, transmittance roulette) are described. */
#ifndef VOLMC_TRACKING_H
#define VOLMC_TRACKING_H

#include "params.h"
#include "rng.h"
#include "sampling.h"
#include "medium.h"

/* Guard "transmittance roulette": returns 0 when the walk ends (T is then 0). */
static inline int transmittance_roulette(float *T, Rng *rng) {
    float a = fabs(*T);
    if (!(a < TR_RR_THRESHOLD)) return 1;
    if (a == 0.0f || rng_next(rng) * TR_RR_THRESHOLD >= a) {
        *T = 0.0f;
        return 0;
    }
    *T = *T > 0.0f ? TR_RR_THRESHOLD : -TR_RR_THRESHOLD;
    return 1;
}

/* Guard "transmittance roulette" on a spec weight (twin of spec_roulette in tracking.py):
 * by its largest |component|; grey builds play the scalar roulette. */
static inline int spec_roulette(spec *T, Rng *rng) {
#if FEATURE_CHROMATIC
    float a = spec_max(fabs(*T));
    if (!(a < TR_RR_THRESHOLD)) return 1;
    if (a == 0.0f || rng_next(rng) * TR_RR_THRESHOLD >= a) {
        *T = 0.0f;
        return 0;
    }
    *T *= TR_RR_THRESHOLD / a;
    return 1;
#else
    return transmittance_roulette(T, rng);
#endif
}

/* What one tentative collision adds to the emission estimate (twin in tracking.py). */
static inline float3 emission_term(const MediumData *med, float3 p, float mu, float s_maj,
                                   float3 W) {
    float3 k = spec_rgb(medium_chroma(med));
    float3 sa = (1.0f - vec3(med->m.albedo)) * k * (mu / s_maj);
    return sa * emitted_radiance(med, p) * W;
}

/* Hero MIS: balance-heuristic weights R / mean(R) (twin in tracking.py). */
static inline float3 mis_weights(float3 R) {
    float s = (R.x + R.y + R.z) / 3.0f;
    if (!(s > 0.0f)) return (float3)(0.0f);
    return R / s;
}

#if FEATURE_CHROMATIC
/* Spectral tracking's choice at a tentative collision (twin in tracking.py): returns 1 if
 * real; writes the weight factor. */
static inline int spectral_choice(float3 W, float3 k, float mu, float s_maj, float u, float3 *f) {
    float a = spec_max(W * k * mu);
    float3 n = s_maj - k * mu;
    float b = spec_max(W * n);
    if (!(a + b > 0.0f)) {
        *f = (float3)(0.0f);
        return 0;
    }
    if (u * (a + b) < a) {
        *f = k * (mu * (a + b) / (s_maj * a));
        return 1;
    }
    *f = n * ((a + b) / (s_maj * b));
    return 0;
}
#endif

/* render.transmittance = "auto": the technique for one majorant segment of extinction bounds
 * [s_min, s_maj] and length L (twin in tracking.py, where the rule and its measurements are). */
static inline int auto_segment_technique(float s_maj, float s_min, float L) {
    return (s_maj - s_min) * L <= AUTO_THIN_DEPTH ? TRACK_RESIDUAL_RATIO : TRACK_LENGTH;
}

/* Walks o + t d over [t0, t1]. Returns the event; writes the distance (t1 on escape) to
 * *t_out, the transmittance estimate or flight weight to *T_out and the emission gathered
 * (free flight, per unit beta) to *E_out. */
/* Always inlined: each call site passes a constant technique, so the compiler keeps only that
 * technique's code in the loop. */
static inline __attribute__((always_inline)) int track(const MediumData *med, float3 o, float3 d,
                                                       float t0, float t1, int technique,
                                                       int use_control, float3 beta, int hero,
                                                       Rng *rng, ulong *counters, int max_steps,
                                                       float *t_out, spec *T_out, float3 *E_out) {
    /* Plain constants 0 in builds without the feature: they lead any condition they join,
     * since clang warns of a logical operator whose right operand is constant. */
    const int spectral = FEATURE_CHROMATIC ? med->m.spectral != SPECTRAL_GREY : 0;
    const int emissive = FEATURE_EMISSION ? technique == TRACK_FREE_FLIGHT &&
                                                med->m.emission_kind != EMISSION_NONE : 0;
    const spec k = medium_chroma(med);
    o = o + t0 * d;
    MajorantIter it;
    majorant_iter_init(&it, med, o, d, 0.0f, t1 - t0);
    float budget = -1.0f; /* optical depth left to the next tentative collision; < 0: not drawn */
    spec T = 1.0f;
    float3 E = (float3)(0.0f);
    int steps = 0;
    Segment seg;
    *t_out = t1;
    *E_out = E;
    while (majorant_next(&it, med, &seg)) {
        float ta = seg.t_min, tb = seg.t_max, s_maj = seg.sigma_maj;
        int homogeneous = seg.sigma_min == s_maj;
        /* This segment's technique: the walk's own, or auto's choice for it. */
        const int tech = technique == TRACK_AUTO ? auto_segment_technique(s_maj, seg.sigma_min,
                                                                           tb - ta)
                                                 : technique;
        const int flight = tech == TRACK_FREE_FLIGHT || tech == TRACK_LENGTH;
        /* Roulette on the product so far before spending work on another segment (a no-op
         * while T >= TR_RR_THRESHOLD, so on the first segment). Grey track length keeps its
         * estimate 0 or 1: a fraction left by homogeneous segments goes on with probability T
         * as 1, so a shadow ray stops in a dense homogeneous core as soon as delta tracking
         * would, while a homogeneous medium (one segment) stays exact. */
        if (!spectral && technique == TRACK_LENGTH && spec_first(T) < 1.0f) {
            if (rng_next(rng) >= spec_first(T)) {
                *T_out = 0.0f;
                *E_out = E;
                return EVENT_ESCAPE;
            }
            T = 1.0f;
        }
        if (technique != TRACK_FREE_FLIGHT && !spec_roulette(&T, rng)) {
            *T_out = T;
            *E_out = E;
            return EVENT_ESCAPE;
        }
        if (homogeneous && technique != TRACK_FREE_FLIGHT) {
            T *= exp(-(k * s_maj) * (tb - ta));
            continue;
        }
        float control = (homogeneous || tech == TRACK_RESIDUAL_RATIO || (flight && use_control))
                            ? seg.sigma_min : 0.0f;
        float rate = tech == TRACK_RESIDUAL_RATIO ? s_maj - control : s_maj;
        float inv_rate = 1.0f / rate; /* a multiplication per step instead of a division */
        if (tech == TRACK_RESIDUAL_RATIO) T *= exp(-(k * control) * (tb - ta));
        spec w = 1.0f;                        /* next flight: weight of the current vertex */
        /* next flight: this segment's estimate (no exp for the other techniques) */
        spec acc = technique == TRACK_NEXT_FLIGHT ? exp(-s_maj * (tb - ta)) : 0.0f;
        float t = ta;
        float pdf;
        if (budget < 0.0f) budget = sample_exponential(rng_next(rng), 1.0f, &pdf);
        while (true) {
            float step = budget * inv_rate;
            if (t + step >= tb) {
                /* >= 0: rounding must not turn what is left into the "not drawn" marker */
                budget = fmax(budget - rate * (tb - t), 0.0f);
                break;
            }
            t += step;
            float3 p = o + t * d;
#if FEATURE_CHROMATIC
            if (flight && spectral) {
                /* Spectral tracking: the density of a homogeneous segment needs no lookup. */
                float mu = homogeneous ? s_maj : extinction(med, p, s_maj, counters);
                float3 W;
                if (hero >= 0) {
                    /* The hero's one-hot weights: its delta tracking decides (tracking.py). */
                    W = (float3)(hero == 0 ? 1.0f : 0.0f, hero == 1 ? 1.0f : 0.0f,
                                 hero == 2 ? 1.0f : 0.0f);
                    if (emissive) E += emission_term(med, p, mu, s_maj, mis_weights(T * beta));
                } else {
                    W = technique == TRACK_FREE_FLIGHT ? T * beta : T;
                    if (emissive) E += emission_term(med, p, mu, s_maj, T);
                }
                float3 f;
                int real = spectral_choice(W, k, mu, s_maj, rng_next(rng), &f);
                if (real) {
                    *t_out = t0 + t;
                    *T_out = tech == TRACK_LENGTH ? (float3)(0.0f) : T * f;
                    *E_out = E;
                    return EVENT_SCATTER;
                }
                T *= f;
                if (spec_max(T) <= 0.0f) {
                    *T_out = 0.0f;
                    *E_out = E;
                    return EVENT_ESCAPE;
                }
                /* Only the ratios matter to hero MIS: keep them from overflowing. */
                if (hero >= 0) T *= 1.0f / spec_max(T);
            } else
#endif
            if (flight) {
                /* Real for sure where the control covers the majorant (no draw, no lookup). */
                int real = control >= s_maj;
                float mu = real ? s_maj : -1.0f; /* -1: not looked up */
                if (!real) {
                    float um = rng_next(rng) * s_maj;
                    real = um < control;
                    if (!real) {
                        mu = extinction(med, p, s_maj, counters);
                        real = um < mu;
                    }
                }
                if (emissive) {
                    if (mu < 0.0f) mu = extinction(med, p, s_maj, counters);
                    E += emission_term(med, p, mu, s_maj, (float3)(1.0f));
                }
                if (real) {
                    *t_out = t0 + t;
                    *T_out = technique == TRACK_FREE_FLIGHT ? 1.0f : 0.0f;
                    *E_out = E;
                    return EVENT_SCATTER;
                }
            } else if (technique == TRACK_NEXT_FLIGHT) {
                w *= 1.0f - k * (extinction(med, p, s_maj, counters) / s_maj);
                if (!spec_roulette(&w, rng)) {
                    budget = -1.0f; /* the next segment draws afresh */
                    break;
                }
                acc += w * exp(-s_maj * (tb - t));
            } else {
                T *= 1.0f - k * ((extinction(med, p, s_maj, counters) - control) / rate);
                if (!spec_roulette(&T, rng)) {
                    *T_out = T;
                    *E_out = E;
                    return EVENT_ESCAPE;
                }
            }
            budget = sample_exponential(rng_next(rng), 1.0f, &pdf);
            if (++steps >= max_steps) {
                counters[C_CAPPED] += 1;
                if (technique == TRACK_NEXT_FLIGHT) T *= acc;
                if (technique == TRACK_LENGTH) T = 0.0f;
                *t_out = t0 + t;
                *T_out = T;
                *E_out = E;
                return EVENT_CAPPED;
            }
        }
        if (technique == TRACK_NEXT_FLIGHT) T *= acc;
    }
    *T_out = T;
    *E_out = E;
    return EVENT_ESCAPE;
}

#endif
