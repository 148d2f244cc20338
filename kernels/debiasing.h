/* Bias-corrected ray marching on one majorant segment: the telescoping estimator (Misso et al.
 * 2022, unbiased) and the jackknife estimator (low bias). Twin of volmc/reference/debiasing.py,
 * where the estimators, constants, caps and guards are documented; the operation order and the
 * random-number consumption here follow it step by step, per lane. Compiled with
 * -DVOLMC_DEBIASING. Both return spec: channel c's optical depth is medium_chroma(med) x tau
 * from the same lookups (grey builds: lfloat, the scalar arithmetic). */
#ifndef VOLMC_DEBIASING_H
#define VOLMC_DEBIASING_H

#include "params.h"
#include "lanes.h"
#include "medium.h"
#include "rng.h"
#include "guards.h"

/* TELESCOPE_* and JACKKNIFE_* come from the generated params.h (volmc/constants.py). */

static inline lint telescoping_levels(lfloat v, lint n, int max_steps, lmask *capped) {
    lint k = (lint)(0);
    lfloat q = (lfloat)(TELESCOPE_CONTINUE); /* P(K >= k + 1) */
    for (int level = 0; level < TELESCOPE_MAX_LEVEL && ANY(v <= q); ++level) {
        lmask up = v <= q;
        k = k + (up & 1);
        q = select(q, q * TELESCOPE_CONTINUE, up);
    }
    *capped = v <= q; /* the draw asks for a level past the cap */
    /* n 2^k > max_steps, without the overflow of n << 16: n > floor(max_steps / 2^k). */
    lmask over = k > 0 && n > ((lint)(max_steps) >> k);
    while (ANY(over)) {
        k = k - (over & 1);
        *capped = *capped | over;
        over = k > 0 && n > ((lint)(max_steps) >> k);
    }
    return k;
}

/* v, or 0 in each channel that is not finite. */
static inline spec finite_or_zero3(spec v) {
#if FEATURE_CHROMATIC
    return v3(select((lfloat)(0.0f), v.x, finite_bits(v.x)),
              select((lfloat)(0.0f), v.y, finite_bits(v.y)),
              select((lfloat)(0.0f), v.z, finite_bits(v.z)));
#else
    return select((lfloat)(0.0f), v, finite_bits(v));
#endif
}

static inline spec telescoping_segment(const MediumData *med, lvec3 o, lvec3 d, lfloat t0,
                                       lfloat t1, lfloat mbar, lfloat mu_c, Rng *rng,
                                       lulong *counters, int max_steps, lmask active) {
    lfloat L = t1 - t0;
    lmask on = active & !segment_degenerate(L, mbar, counters, max_steps, 1, active);
    uspec kc = medium_chroma(med);
    lint n = comb_count(TELESCOPE_SAMPLES_PER_MFP * mbar * L);
    lfloat v = 1.0f - rng_next(rng, on);
    lmask capped = n > max_steps;
    n = min(n, max_steps);
    lmask cut;
    lint k_max = telescoping_levels(v, n, max_steps, &cut);
    counters[C_CAPPED] += lane_ones(on & (capped | cut));
    lfloat a = rng_next(rng, on);
    lfloat h = L / to_lfloat(n);
    lfloat s = (lfloat)(0.0f);
    for (int j = 0; ANY(on & (j < n)); ++j) {
        lmask look = on & (j < n);
        s += select((lfloat)(0.0f),
                    extinction(med, madd3(o, d, t0 + ((float)j + a) * h), mbar, counters, look),
                    look);
    }
    spec y = spec_exp_neg(kc, s * h);
    spec est = y;
    float w = 1.0f;
    lint m = n;
    for (int k = 0; ANY(on & (k < k_max)); ++k) {
        lmask level = on & (k < k_max);
        lfloat a2 = a + a;
        /* level k-1's points have parity floor(2 a) = 1 - odd */
        lint odd = select((lint)(0), (lint)(1), a2 < 1.0f);
        a = select(a, select(a2 - 1.0f, a2, a2 < 1.0f), level);
        h = select(h, h * 0.5f, level);
        lfloat s_new = (lfloat)(0.0f);
        for (int j = 0; ANY(level & (j < m)); ++j) {
            lmask look = level & (j < m);
            s_new += select((lfloat)(0.0f),
                            extinction(med, madd3(o, d, t0 + (to_lfloat(2 * j + odd) + a) * h),
                                       mbar, counters, look),
                            look);
        }
        s = select(s, s + s_new, level);
        m = select(m, m + m, level);
        w *= TELESCOPE_CONTINUE;
        spec y_next = spec_exp_neg(kc, s * h);
        est = spec_sel(est, spec_add(est, spec_div(spec_sub(y_next, y), (lfloat)(w))), level);
        y = spec_sel(y, y_next, level);
    }
    return spec_sel(spec_s((lfloat)(1.0f)), finite_or_zero3(est), on);
}

/* The jackknife estimate of one channel, whose combs are k xs (k its chroma). */
static inline lfloat jackknife_channel(const lfloat *xs, float k) {
    int g = JACKKNIFE_GROUPS;
    lfloat total = (lfloat)(0.0f);
    for (int i = 0; i < g; ++i) total += k * xs[i];
    lfloat xbar = total / (float)g;
    lfloat acc = (lfloat)(0.0f);
    for (int i = 0; i < g; ++i) acc += exp((k * xs[i] - xbar) / (float)(g - 1));
    lfloat pre = exp(-xbar);
    lfloat est = pre * ((float)g - (float)(g - 1) * acc / (float)g);
    return select(select((lfloat)(0.0f), est, finite_bits(est)), (lfloat)(0.0f), pre == 0.0f);
}

static inline spec jackknife_segment(const MediumData *med, lvec3 o, lvec3 d, lfloat t0,
                                     lfloat t1, lfloat mbar, lfloat mu_c, Rng *rng,
                                     lulong *counters, int max_steps, lmask active) {
    lfloat L = t1 - t0;
    int g = JACKKNIFE_GROUPS;
    lmask on = active & !segment_degenerate(L, mbar, counters, max_steps, g, active);
    lint m = comb_count(JACKKNIFE_SAMPLES_PER_MFP * mbar * L / (float)g);
    lmask over = on & (g * m > max_steps);
    counters[C_CAPPED] += lane_ones(over);
    m = select(m, (lint)(max_steps / g), over);
    lfloat xs[JACKKNIFE_GROUPS];
    for (int i = 0; i < g; ++i)
        xs[i] = optical_depth_comb(med, o, d, t0, L, m, rng_next(rng, on), mbar, counters, on);
#if FEATURE_CHROMATIC
    float3 k = medium_chroma(med);
    spec T = v3(jackknife_channel(xs, k.x), jackknife_channel(xs, k.y),
                jackknife_channel(xs, k.z));
#else
    spec T = jackknife_channel(xs, 1.0f);
#endif
    return spec_sel(spec_s((lfloat)(1.0f)), T, on);
}

#endif
