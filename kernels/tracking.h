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

/* Walks o + t d over [t0, t1]. Returns the event; writes the distance (t1 on escape) to
 * *t_out and the transmittance estimate to *T_out. */
/* Always inlined: each call site passes a constant technique, so the compiler keeps only that
 * technique's code in the loop. */
inline __attribute__((always_inline)) int track(const MediumData *med, float3 o, float3 d,
                                                float t0, float t1, int technique,
                                                int use_control, Rng *rng, ulong *counters,
                                                int max_steps, float *t_out, float *T_out) {
    o = o + t0 * d;
    MajorantIter it;
    majorant_iter_init(&it, med, o, d, 0.0f, t1 - t0);
    int flight = technique == TRACK_FREE_FLIGHT || technique == TRACK_LENGTH;
    float budget = -1.0f; /* optical depth left to the next tentative collision; < 0: not drawn */
    float T = 1.0f;
    int steps = 0;
    Segment seg;
    *t_out = t1;
    while (majorant_next(&it, med, &seg)) {
        float ta = seg.t_min, tb = seg.t_max, s_maj = seg.sigma_maj;
        int homogeneous = seg.sigma_min == s_maj;
        /* Roulette on the product so far before spending work on another segment (a no-op
         * while T >= TR_RR_THRESHOLD, so on the first segment). Track length keeps its
         * estimate 0 or 1: a fraction left by homogeneous segments goes on with probability T
         * as 1, so a shadow ray stops in a dense homogeneous core as soon as delta tracking
         * would, while a homogeneous medium (one segment) stays exact. */
        if (technique == TRACK_LENGTH && T < 1.0f) {
            if (rng_next(rng) >= T) {
                *T_out = 0.0f;
                return EVENT_ESCAPE;
            }
            T = 1.0f;
        }
        if (technique != TRACK_FREE_FLIGHT && !transmittance_roulette(&T, rng)) {
            *T_out = T;
            return EVENT_ESCAPE;
        }
        if (homogeneous && technique != TRACK_FREE_FLIGHT) {
            T *= exp(-s_maj * (tb - ta));
            continue;
        }
        float control = (homogeneous || technique == TRACK_RESIDUAL_RATIO ||
                         (flight && use_control)) ? seg.sigma_min : 0.0f;
        float rate = technique == TRACK_RESIDUAL_RATIO ? s_maj - control : s_maj;
        float inv_rate = 1.0f / rate; /* a multiplication per step instead of a division */
        if (technique == TRACK_RESIDUAL_RATIO) T *= exp(-control * (tb - ta));
        float w = 1.0f;                       /* next flight: weight of the current vertex */
        /* next flight: this segment's estimate (no exp for the other techniques) */
        float acc = technique == TRACK_NEXT_FLIGHT ? exp(-s_maj * (tb - ta)) : 0.0f;
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
            if (flight) {
                /* Real for sure where the control covers the majorant (no draw, no lookup). */
                int real = control >= s_maj;
                if (!real) {
                    float um = rng_next(rng) * s_maj;
                    real = um < control || um < extinction(med, p, s_maj, counters);
                }
                if (real) {
                    *t_out = t0 + t;
                    *T_out = 0.0f;
                    return EVENT_SCATTER;
                }
            } else if (technique == TRACK_NEXT_FLIGHT) {
                w *= 1.0f - extinction(med, p, s_maj, counters) / s_maj;
                if (!transmittance_roulette(&w, rng)) {
                    budget = -1.0f; /* the next segment draws afresh */
                    break;
                }
                acc += w * exp(-s_maj * (tb - t));
            } else {
                T *= 1.0f - (extinction(med, p, s_maj, counters) - control) / rate;
                if (!transmittance_roulette(&T, rng)) {
                    *T_out = T;
                    return EVENT_ESCAPE;
                }
            }
            budget = sample_exponential(rng_next(rng), 1.0f, &pdf);
            if (++steps >= max_steps) {
                counters[C_CAPPED] += 1;
                if (technique == TRACK_NEXT_FLIGHT) T *= acc;
                *t_out = t0 + t;
                *T_out = flight ? 0.0f : T;
                return EVENT_CAPPED;
            }
        }
        if (technique == TRACK_NEXT_FLIGHT) T *= acc;
    }
    *T_out = T;
    return EVENT_ESCAPE;
}

#endif
