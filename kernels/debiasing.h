/* Bias-corrected ray marching on one majorant segment: the telescoping estimator (Misso et al.
 * 2022, unbiased) and the jackknife estimator (low bias). Twin of volmc/reference/debiasing.py,
 * where the estimators, constants, caps and guards are documented; the operation order and the
 * random-number consumption here follow it step by step. Compiled with -DVOLMC_DEBIASING.
 * Both return spec: channel c's optical depth is medium_chroma(med) x tau from the same
 * lookups (grey builds: float, the scalar arithmetic). */
#ifndef VOLMC_DEBIASING_H
#define VOLMC_DEBIASING_H

#include "params.h"
#include "medium.h"
#include "rng.h"
#include "guards.h"

/* TELESCOPE_* and JACKKNIFE_* come from the generated params.h (volmc/constants.py). */

static inline int telescoping_levels(float v, int n, int max_steps, bool *capped) {
    int k = 0;
    float q = TELESCOPE_CONTINUE; /* P(K >= k + 1) */
    while (v <= q && k < TELESCOPE_MAX_LEVEL) {
        k += 1;
        q *= TELESCOPE_CONTINUE;
    }
    *capped = v <= q; /* the draw asks for a level past the cap */
    while (k > 0 && ((long)n << k) > (long)max_steps) { /* long: n 2^16 overflows int */
        k -= 1;
        *capped = true;
    }
    return k;
}

/* v, or 0 in each channel that is not finite. */
static inline spec finite_or_zero3(spec v) {
#if FEATURE_CHROMATIC
    return (float3)(finite_bits(v.x) ? v.x : 0.0f, finite_bits(v.y) ? v.y : 0.0f,
                    finite_bits(v.z) ? v.z : 0.0f);
#else
    return finite_bits(v) ? v : 0.0f;
#endif
}

static inline spec telescoping_segment(const MediumData *med, float3 o, float3 d, float t0,
                                       float t1, float mbar, float mu_c, Rng *rng, ulong *counters,
                                       int max_steps) {
    float L = t1 - t0;
    if (segment_degenerate(L, mbar, counters, max_steps, 1)) return 1.0f;
    spec kc = medium_chroma(med);
    int n = max(1, (int)ceil(TELESCOPE_SAMPLES_PER_MFP * mbar * L));
    float v = 1.0f - rng_next(rng);
    bool capped = n > max_steps;
    if (capped) n = max_steps;
    bool cut;
    int k_max = telescoping_levels(v, n, max_steps, &cut);
    if (capped || cut) counters[C_CAPPED] += 1;
    float a = rng_next(rng);
    float h = L / (float)n;
    float s = 0.0f;
    for (int j = 0; j < n; ++j)
        s += extinction(med, o + (t0 + ((float)j + a) * h) * d, mbar, counters);
    spec y = exp(-(kc * (s * h)));
    spec est = y;
    float w = 1.0f;
    int m = n;
    for (int k = 0; k < k_max; ++k) {
        float a2 = a + a;
        int odd = a2 < 1.0f ? 1 : 0; /* level k-1's points have parity floor(2 a) = 1 - odd */
        a = odd == 1 ? a2 : a2 - 1.0f;
        h *= 0.5f;
        float s_new = 0.0f;
        for (int j = 0; j < m; ++j)
            s_new += extinction(med, o + (t0 + ((float)(2 * j + odd) + a) * h) * d, mbar,
                                counters);
        s += s_new;
        m += m;
        w *= TELESCOPE_CONTINUE;
        spec y_next = exp(-(kc * (s * h)));
        est += (y_next - y) / w;
        y = y_next;
    }
    return finite_or_zero3(est);
}

/* The jackknife estimate of one channel, whose combs are k xs (k its chroma). */
static inline float jackknife_channel(const float *xs, float k) {
    int g = JACKKNIFE_GROUPS;
    float total = 0.0f;
    for (int i = 0; i < g; ++i) total += k * xs[i];
    float xbar = total / (float)g;
    float acc = 0.0f;
    for (int i = 0; i < g; ++i) acc += exp((k * xs[i] - xbar) / (float)(g - 1));
    float pre = exp(-xbar);
    if (pre == 0.0f) return 0.0f;
    float est = pre * ((float)g - (float)(g - 1) * acc / (float)g);
    return finite_bits(est) ? est : 0.0f;
}

static inline spec jackknife_segment(const MediumData *med, float3 o, float3 d, float t0, float t1,
                                     float mbar, float mu_c, Rng *rng, ulong *counters,
                                     int max_steps) {
    float L = t1 - t0;
    int g = JACKKNIFE_GROUPS;
    if (segment_degenerate(L, mbar, counters, max_steps, g)) return 1.0f;
    int m = max(1, (int)ceil(JACKKNIFE_SAMPLES_PER_MFP * mbar * L / (float)g));
    if (g * m > max_steps) {
        counters[C_CAPPED] += 1;
        m = max_steps / g;
    }
    float xs[JACKKNIFE_GROUPS];
    for (int i = 0; i < g; ++i)
        xs[i] = optical_depth_comb(med, o, d, t0, L, m, rng_next(rng), mbar, counters);
#if FEATURE_CHROMATIC
    float3 k = medium_chroma(med);
    return (float3)(jackknife_channel(xs, k.x), jackknife_channel(xs, k.y),
                    jackknife_channel(xs, k.z));
#else
    return jackknife_channel(xs, 1.0f);
#endif
}

#endif
