/* Transmittance estimators on one interface:
 *   spec transmittance_<name>(const MediumData *med, lvec3 o, lvec3 d, lfloat t0, lfloat t1,
 *                             Rng *rng, lulong *counters, int max_steps, lmask active)
 * (spec: RGB with FEATURE_CHROMATIC; the power series stay grey, one value for all channels)
 * Twin of volmc/reference/estimators.py (the two families, the per-segment driver and the
 * exact treatment of homogeneous segments are described there); the registry of names is
 * volmc/techniques.py. The power series (power_series.h) are compiled in only with
 * -DVOLMC_POWER_SERIES, the telescoping and jackknife estimators (debiasing.h) only with
 * -DVOLMC_DEBIASING: the build options their registry records carry. One estimate per lane,
 * in the active lanes. */
#ifndef VOLMC_ESTIMATORS_H
#define VOLMC_ESTIMATORS_H

#include "params.h"
#include "lanes.h"
#include "rng.h"
#include "medium.h"
#include "tracking.h"
/* Outside the #ifdefs: the source assembler expands each header once, where it first appears,
 * so a header both optional families include must come before either. */
#include "guards.h"
#ifdef VOLMC_POWER_SERIES
#include "power_series.h"
#endif
#ifdef VOLMC_DEBIASING
#include "debiasing.h"
#endif

static inline spec biased_raymarch_segment(const MediumData *med, lvec3 o, lvec3 d, lfloat t0,
                                           lfloat t1, lfloat mbar, lfloat mu_c, Rng *rng,
                                           lulong *counters, int max_steps, lmask active) {
    lfloat L = fmax(t1 - t0, 0.0f);
    lmask on = active & !(mbar <= 0.0f || L <= 0.0f);
    lint n = comb_count(RAYMARCH_SAMPLES_PER_MFP * mbar * L);
    counters[C_CAPPED] += lane_ones(on & (n > max_steps));
    n = min(n, max_steps);
    lfloat tau = optical_depth_comb(med, o, d, t0, L, n, rng_next(rng, on), mbar, counters, on);
    return spec_sel(spec_s((lfloat)(1.0f)), spec_exp_neg(medium_chroma(med), tau), on);
}

static inline spec segment_estimate(int kind, const MediumData *med, lvec3 o, lvec3 d,
                                    lfloat t0, lfloat t1, lfloat s_maj, lfloat s_min, Rng *rng,
                                    lulong *counters, int max_steps, lmask active) {
    if (kind == SEGMENT_BIASED_RAYMARCH)
        return biased_raymarch_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters,
                                       max_steps, active);
#ifdef VOLMC_POWER_SERIES
    if (kind == SEGMENT_POWER_SERIES)
        return spec_s(power_series_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters,
                                           max_steps, active));
    if (kind == SEGMENT_UNBIASED_RAYMARCH)
        return spec_s(unbiased_raymarch_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters,
                                                max_steps, active));
#endif
#ifdef VOLMC_DEBIASING
    if (kind == SEGMENT_TELESCOPING)
        return telescoping_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters, max_steps,
                                   active);
    if (kind == SEGMENT_JACKKNIFE)
        return jackknife_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters, max_steps,
                                 active);
#endif
    return spec_exp_neg(medium_chroma(med), s_maj * (t1 - t0)); /* SEGMENT_ANALYTIC */
}

/* RGB in chromatic builds, with transmittance roulette on the largest channel (spec_roulette).
 * The lanes walk their segments together: one segment per lane and iteration. */
static inline spec transmittance_by_segments(const MediumData *med, lvec3 o, lvec3 d, lfloat t0,
                                             lfloat t1, int kind, Rng *rng, lulong *counters,
                                             int max_steps, lmask active) {
    o = madd3(o, d, t0);
    MajorantIter it = {0};   /* records start defined in every lane (lanes.h) */
    majorant_iter_init(&it, med, o, d, (lfloat)(0.0f), t1 - t0, active);
    uspec k = medium_chroma(med);
    spec T = spec_s((lfloat)(1.0f));
    Segment seg = {0};
    lmask live = active;
    while (ANY(live)) {
        counters[C_LANE_ROUNDS] += lane_ones(LANE_IOTA == 0);
        counters[C_LANE_ACTIVE] += lane_ones(live);
        live = majorant_next(&it, med, &seg, live);
        live = spec_roulette(&T, rng, live);
        lmask hom = live & (seg.sigma_min == seg.sigma_maj);
        T = spec_sel(T, spec_mul(T, spec_exp_neg(k, seg.sigma_maj * (seg.t_max - seg.t_min))),
                     hom);
        lmask est = live & !hom;
        if (ANY(est))
            T = spec_sel(T, spec_mul(T, segment_estimate(kind, med, o, d, seg.t_min, seg.t_max,
                                                         seg.sigma_maj, seg.sigma_min, rng,
                                                         counters, max_steps, est)),
                         est);
    }
    return T;
}

#define TRANSMITTANCE_ARGS const MediumData *med, lvec3 o, lvec3 d, lfloat t0, lfloat t1, \
    Rng *rng, lulong *counters, int max_steps, lmask active

static inline spec transmittance_analytic(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, SEGMENT_ANALYTIC, rng, counters,
                                     max_steps, active);
}

/* The tracking estimators return spec too. */
static inline spec tracked_transmittance(TRANSMITTANCE_ARGS, int technique) {
    lfloat t;
    spec T;
    lvec3 E;
    track(med, o, d, t0, t1, technique, technique == TRACK_LENGTH || technique == TRACK_AUTO,
          v3s(1.0f), (lint)(-1), emis_plain(), rng, counters, max_steps, active, &t, &T, &E);
    return T;
}

static inline spec transmittance_track_length(TRANSMITTANCE_ARGS) {
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps, active,
                                 TRACK_LENGTH);
}

static inline spec transmittance_ratio_tracking(TRANSMITTANCE_ARGS) {
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps, active,
                                 TRACK_RATIO);
}

static inline spec transmittance_residual_ratio(TRANSMITTANCE_ARGS) {
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps, active,
                                 TRACK_RESIDUAL_RATIO);
}

static inline spec transmittance_next_flight(TRANSMITTANCE_ARGS) {
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps, active,
                                 TRACK_NEXT_FLIGHT);
}

#if defined(VOLMC_POWER_SERIES) && defined(VOLMC_DEBIASING)
/* render.transmittance = "auto" (twins in estimators.py, which say why). */
static inline int auto_alone_kind(const MediumData *med) {
    return (FEATURE_CHROMATIC ? med->m[0].spectral != SPECTRAL_GREY : 0) ? SEGMENT_TELESCOPING
                                                                      : SEGMENT_UNBIASED_RAYMARCH;
}

static inline spec transmittance_auto(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, auto_alone_kind(med), rng, counters,
                                     max_steps, active);
}
#endif

static inline spec transmittance_auto_shadow(TRANSMITTANCE_ARGS) {
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps, active,
                                 TRACK_AUTO);
}

static inline spec transmittance_biased_raymarch(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, SEGMENT_BIASED_RAYMARCH, rng,
                                     counters, max_steps, active);
}

#ifdef VOLMC_POWER_SERIES
static inline spec transmittance_power_series(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, SEGMENT_POWER_SERIES, rng, counters,
                                     max_steps, active);
}

static inline spec transmittance_unbiased_raymarch(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, SEGMENT_UNBIASED_RAYMARCH, rng,
                                     counters, max_steps, active);
}
#endif

#ifdef VOLMC_DEBIASING
static inline spec transmittance_telescoping(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, SEGMENT_TELESCOPING, rng, counters,
                                     max_steps, active);
}

static inline spec transmittance_jackknife(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, SEGMENT_JACKKNIFE, rng, counters,
                                     max_steps, active);
}
#endif

#endif
