/* Power-series transmittance estimators on one majorant segment: unbiased ray marching (Kettunen
 * et al. 2021) and the p-series CMF estimator (Georgiev et al. 2019). Twin of
 * volmc/reference/power_series.py, where the formulas, parameters, caps and numerical guards are
 * documented; the operation order and the random-number consumption here follow it step by step. */
#ifndef VOLMC_POWER_SERIES_H
#define VOLMC_POWER_SERIES_H

#include "params.h"
#include "medium.h"
#include "rng.h"
#include "guards.h"

/* URM_*, CMF_GOAL and CMF_FIT_* come from the generated params.h (volmc/constants.py). */

static inline int cmf_lookup_budget(float lam) {
    return (int)ceil(cbrt((CMF_FIT_0 + lam) * (CMF_FIT_1 + lam) * (CMF_FIT_2 + lam)));
}

static inline int urm_comb_size(float lam) {
    return max(1, (int)floor((float)cmf_lookup_budget(lam) / (1.0f + URM_MEAN_ORDER) + 0.5f));
}

/* Log-domain pmf: exp(-lam) alone underflows in float32 from lam ~ 104 on. */
static inline int cmf_deterministic_terms(float lam, int limit) {
    float log_p = -lam;
    float cmf = exp(log_p);
    float log_lam = lam > 0.0f ? log(lam) : 0.0f;
    int q = 0;
    while (cmf < CMF_GOAL && q < limit) {
        q += 1;
        log_p += log_lam - log((float)q);
        cmf += exp(log_p);
    }
    return q + 1;
}

static inline float urm_order_ratio(int k) {
    if (k == 1) return 1.0f - URM_P_ZERO;
    if (k <= URM_K) return 1.0f;
    return fmin(1.0f, URM_C / (float)k);
}

/* Elementary symmetric means updated online (convex blends: no overflow, no cancellation). */
static inline float urm_series(float x0, const float *ys, int n) {
    float e[URM_MAX_ORDER + 1];
    e[0] = 1.0f;
    for (int k = 1; k <= n; ++k) e[k] = 0.0f;
    for (int i = 1; i <= n; ++i) {
        float y = ys[i - 1];
        float inv_i = 1.0f / (float)i;
        for (int k = i; k >= 1; --k) e[k] += ((float)k * inv_i) * (e[k - 1] * y - e[k]);
    }
    float s = 1.0f;
    float w = 1.0f;
    for (int k = 1; k <= n; ++k) {
        w /= (float)k * urm_order_ratio(k);
        s += e[k] * w;
    }
    float pre = exp(-x0);
    if (pre == 0.0f) return 0.0f;
    float est = pre * s;
    return finite_bits(est) ? est : 0.0f;  /* guards.h: survives fast-math */
}

static inline float unbiased_raymarch_segment(const MediumData *med, float3 o, float3 d, float t0,
                                              float t1, float mbar, float mu_c, Rng *rng,
                                              ulong *counters, int max_steps) {
    float L = t1 - t0;
    if (segment_degenerate(L, mbar, counters, max_steps, 1)) return 1.0f;
    int m = urm_comb_size(mbar * L); /* mu_c unused: the control is the online comb x0 */
    /* Order before any lookup: independent of the combs, and the cost is known up front. */
    float v = 1.0f - rng_next(rng);
    int n = 0;
    float q = 1.0f;
    bool capped = false;
    for (;;) {
        float q_next = q * urm_order_ratio(n + 1);
        if (!(v <= q_next)) break;
        if (n == URM_MAX_ORDER) {
            capped = true;
            break;
        }
        n += 1;
        q = q_next;
    }
    if (m * (n + 1) > max_steps) {
        capped = true;
        if (m > max_steps) {
            m = max_steps;
            n = 0;
        } else {
            n = max_steps / m - 1;
        }
    }
    if (capped) counters[C_CAPPED] += 1;
    float x0 = optical_depth_comb(med, o, d, t0, L, m, rng_next(rng), mbar, counters);
    float ys[URM_MAX_ORDER];
    for (int i = 0; i < n; ++i)
        ys[i] = x0 - optical_depth_comb(med, o, d, t0, L, m, rng_next(rng), mbar, counters);
    return urm_series(x0, ys, n);
}

static inline float power_series_segment(const MediumData *med, float3 o, float3 d, float t0,
                                         float t1, float mbar, float mu_c, Rng *rng,
                                         ulong *counters, int max_steps) {
    float L = t1 - t0;
    if (segment_degenerate(L, mbar, counters, max_steps, 1)) return 1.0f;
    float tau_bar = mbar * L;
    float lam = fmax(mbar - fmax(mu_c, 0.0f), 0.0f) * L;
    int n_det = cmf_deterministic_terms(lam, max_steps);
    float v = 1.0f - rng_next(rng);
    /* exp(-tau_bar) spread over the deterministic orders keeps every partial product in
     * float range. */
    float g = exp(-tau_bar / (float)n_det);
    float acc = 1.0f;
    float prod = 1.0f;
    int k = 0;
    while (k < n_det) {
        if (k == max_steps) {
            counters[C_CAPPED] += 1;
            return acc * pown(g, n_det - k);
        }
        k += 1;
        float x = t0 + rng_next(rng) * L;
        float y = (mbar - extinction(med, o + x * d, mbar, counters)) * L;
        prod *= g * y / (float)k;
        acc = acc * g + prod;
        if (prod == 0.0f) return acc * pown(g, n_det - k);
    }
    float q = 1.0f;
    for (;;) {
        q *= fmin(1.0f, lam / (float)(k + 1));
        if (!(v <= q)) break;
        if (k == max_steps) {
            counters[C_CAPPED] += 1;
            break;
        }
        k += 1;
        float x = t0 + rng_next(rng) * L;
        float y = (mbar - extinction(med, o + x * d, mbar, counters)) * L;
        prod *= y / (float)k;
        acc += prod / q;
        if (prod == 0.0f) break;
    }
    return finite_bits(acc) ? acc : 0.0f;
}

#endif
