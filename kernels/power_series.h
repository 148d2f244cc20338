/* Power-series transmittance estimators on one majorant segment: unbiased ray marching (Kettunen
 * et al. 2021) and the p-series CMF estimator (Georgiev et al. 2019). Twin of
 * volmc/reference/power_series.py, where the formulas, parameters, caps and numerical guards are
 * documented; the operation order and the random-number consumption here follow it step by step,
 * per lane. Loops whose trip count differs between lanes run to the largest, each lane masked
 * past its own count. */
#ifndef VOLMC_POWER_SERIES_H
#define VOLMC_POWER_SERIES_H

#include "params.h"
#include "lanes.h"
#include "medium.h"
#include "rng.h"
#include "guards.h"

/* URM_*, CMF_GOAL and CMF_FIT_* come from the generated params.h (volmc/constants.py). */

static inline lint cmf_lookup_budget(lfloat lam) {
    lam = fmin(lam, CMF_FIT_MAX_LAMBDA);
    return to_lint(ceil(cbrt((CMF_FIT_0 + lam) * (CMF_FIT_1 + lam) * (CMF_FIT_2 + lam))));
}

static inline lint urm_comb_size(lfloat lam) {
    return max(1, to_lint(floor(to_lfloat(cmf_lookup_budget(lam)) / (1.0f + URM_MEAN_ORDER) +
                                0.5f)));
}

/* Log-domain pmf: exp(-lam) alone underflows in float32 from lam ~ 104 on. */
static inline lint cmf_deterministic_terms(lfloat lam, int limit, lmask active) {
    lfloat log_p = -lam;
    lfloat cmf = exp(log_p);
    lfloat log_lam = select((lfloat)(0.0f), log(lam), lam > 0.0f);
    lint q = (lint)(0);
    lmask more = active & (cmf < CMF_GOAL) & (q < limit);
    while (ANY(more)) {
        q = q + (more & 1);
        log_p = select(log_p, log_p + (log_lam - log(to_lfloat(q))), more);
        cmf = select(cmf, cmf + exp(log_p), more);
        more = more & (cmf < CMF_GOAL) & (q < limit);
    }
    return q + 1;
}

static inline lfloat urm_order_ratio(lint k) {
    return select(select(fmin((lfloat)(1.0f), URM_C / to_lfloat(k)), (lfloat)(1.0f), k <= URM_K),
                  (lfloat)(1.0f - URM_P_ZERO), k == 1);
}

/* Elementary symmetric means updated online (convex blends: no overflow, no cancellation). */
static inline lfloat urm_series(lfloat x0, const lfloat *ys, lint n, lmask active) {
    lfloat e[URM_MAX_ORDER + 1];
    e[0] = (lfloat)(1.0f);
    for (int k = 1; k <= URM_MAX_ORDER; ++k) e[k] = (lfloat)(0.0f);
    for (int i = 1; i <= URM_MAX_ORDER && ANY(active & (i <= n)); ++i) {
        lmask on = active & (i <= n);
        lfloat y = ys[i - 1];
        float inv_i = 1.0f / (float)i;
        for (int k = i; k >= 1; --k)
            e[k] = select(e[k], e[k] + ((float)k * inv_i) * (e[k - 1] * y - e[k]), on);
    }
    lfloat s = (lfloat)(1.0f);
    lfloat w = (lfloat)(1.0f);
    for (int k = 1; k <= URM_MAX_ORDER && ANY(active & (k <= n)); ++k) {
        lmask on = active & (k <= n);
        w = select(w, w / ((float)k * urm_order_ratio((lint)(k))), on);
        s = select(s, s + e[k] * w, on);
    }
    lfloat pre = exp(-x0);
    lfloat est = pre * s;
    return select(select((lfloat)(0.0f), est, finite_bits(est)), (lfloat)(0.0f), pre == 0.0f);
}

static inline lfloat unbiased_raymarch_segment(const MediumData *med, lvec3 o, lvec3 d,
                                               lfloat t0, lfloat t1, lfloat mbar, lfloat mu_c,
                                               Rng *rng, lulong *counters, int max_steps,
                                               lmask active) {
    lfloat L = t1 - t0;
    lmask on = active & !segment_degenerate(L, mbar, counters, max_steps, 1, active);
    lint m = urm_comb_size(mbar * L); /* mu_c unused: the control is the online comb x0 */
    /* Order before any lookup: independent of the combs, and the cost is known up front. */
    lfloat v = 1.0f - rng_next(rng, on);
    lint n = (lint)(0);
    lfloat q = (lfloat)(1.0f);
    lmask capped = (lmask)(0), more = on;
    while (ANY(more)) {
        lfloat q_next = q * urm_order_ratio(n + 1);
        more = more & (v <= q_next);
        lmask full = more & (n == URM_MAX_ORDER);
        capped = capped | full;
        more = more & !full;
        n = n + (more & 1);
        q = select(q, q_next, more);
    }
    lmask over = on & (m > max_steps / (n + 1)); /* m (n + 1) > max_steps, without overflow */
    capped = capped | over;
    lmask too_fine = over & (m > max_steps);
    n = select(n, select(max_steps / max(m, 1) - 1, (lint)(0), too_fine), over);
    m = select(m, (lint)(max_steps), too_fine);
    counters[C_CAPPED] += lane_ones(on & capped);
    lfloat x0 = optical_depth_comb(med, o, d, t0, L, m, rng_next(rng, on), mbar, counters, on);
    lfloat ys[URM_MAX_ORDER];
    for (int i = 0; i < URM_MAX_ORDER; ++i) {
        lmask ask = on & (i < n);
        if (!ANY(ask)) {
            ys[i] = (lfloat)(0.0f);
            continue;
        }
        ys[i] = x0 - optical_depth_comb(med, o, d, t0, L, m, rng_next(rng, ask), mbar, counters,
                                        ask);
    }
    return select((lfloat)(1.0f), urm_series(x0, ys, n, on), on);
}

/* Twins of cmf_rescale and cmf_scaled_result in power_series.py: acc and prod times the
 * same exact power of two when |acc| leaves [CMF_RESCALE_LO, CMF_RESCALE_HI], e counting it;
 * and acc 2^(CMF_RESCALE_BITS e) exp(-left tau_per_order) in the log domain. */
static inline void cmf_rescale(lfloat *acc, lfloat *prod, lint *e, lmask active) {
    lfloat a = fabs(*acc);
    lmask big = active & (a > CMF_RESCALE_HI);
    lmask small = active & (a > 0.0f) & (a < CMF_RESCALE_LO);
    lfloat f = select(select((lfloat)(1.0f), (lfloat)(CMF_RESCALE_HI), small),
                      (lfloat)(CMF_RESCALE_LO), big);
    *acc = *acc * f;
    *prod = *prod * f;
    *e = *e + (big & 1) - (small & 1);
}

static inline lfloat cmf_scaled_result(lfloat acc, lint e, lint left, lfloat tau_per_order) {
    lfloat r = copysign(exp(log(fabs(acc)) + to_lfloat(e) * CMF_RESCALE_LN -
                            to_lfloat(left) * tau_per_order), acc);
    return select(r, (lfloat)(0.0f), acc == 0.0f || !finite_bits(acc));
}

static inline lfloat power_series_segment(const MediumData *med, lvec3 o, lvec3 d, lfloat t0,
                                          lfloat t1, lfloat mbar, lfloat mu_c, Rng *rng,
                                          lulong *counters, int max_steps, lmask active) {
    lfloat L = t1 - t0;
    lmask on = active & !segment_degenerate(L, mbar, counters, max_steps, 1, active);
    lfloat tau_bar = mbar * L;
    lfloat lam = fmax(mbar - fmax(mu_c, 0.0f), 0.0f) * L;
    lint n_det = cmf_deterministic_terms(lam, max_steps, on);
    /* The CMF goal past the step cap (power_series.py): counted here, since g may underflow
     * and end the walk before it reaches the cap. */
    lmask short_of_goal = on & (n_det > max_steps);
    counters[C_CAPPED] += lane_ones(short_of_goal);
    lfloat v = 1.0f - rng_next(rng, on);
    /* exp(-tau_bar) spread over the deterministic orders keeps every partial product in
     * float range. */
    lfloat g = exp(-tau_bar / to_lfloat(n_det));
    lfloat acc = (lfloat)(1.0f);
    lfloat prod = (lfloat)(1.0f);
    lint e = (lint)(0);
    lint k = (lint)(0);
    /* The deterministic orders: a lane that stops early returns acc g^(n_det - k). */
    lmask more = on & (k < n_det), early = (lmask)(0);
    while (ANY(more)) {
        lmask cap = more & (k == max_steps); /* (counted above) */
        early = early | cap;
        more = more & !cap;
        k = k + (more & 1);
        lfloat x = t0 + rng_next(rng, more) * L;
        lfloat y = (mbar - extinction(med, madd3(o, d, x), mbar, counters, more)) * L;
        prod = select(prod, prod * (g * y / to_lfloat(k)), more);
        acc = select(acc, acc * g + prod, more);
        lmask zero = more & (prod == 0.0f);
        early = early | zero;
        cmf_rescale(&acc, &prod, &e, more & !zero);
        more = more & !zero & (k < n_det);
    }
    lfloat result = cmf_scaled_result(acc, e, n_det - k, tau_bar / to_lfloat(n_det));
    /* The random orders (Russian roulette on the series). */
    more = on & !early;
    lfloat q = (lfloat)(1.0f);
    while (ANY(more)) {
        q = select(q, q * fmin(1.0f, lam / to_lfloat(k + 1)), more);
        more = more & (v <= q);
        lmask cap = more & (k == max_steps);
        counters[C_CAPPED] += lane_ones(cap);
        more = more & !cap;
        k = k + (more & 1);
        lfloat x = t0 + rng_next(rng, more) * L;
        lfloat y = (mbar - extinction(med, madd3(o, d, x), mbar, counters, more)) * L;
        prod = select(prod, prod * (y / to_lfloat(k)), more);
        acc = select(acc, acc + prod / q, more);
        more = more & (prod != 0.0f);
        cmf_rescale(&acc, &prod, &e, more);
    }
    acc = ldexp(acc, e * CMF_RESCALE_BITS);
    acc = select((lfloat)(0.0f), acc, finite_bits(acc));
    return select((lfloat)(1.0f), select(acc, result, early), on);
}

#endif
