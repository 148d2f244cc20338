/* Transmittance estimators on one interface:
 *   spec transmittance_<name>(const MediumData *med, float3 o, float3 d, float t0, float t1,
 *                             Rng *rng, ulong *counters, int max_steps)
 * (spec: RGB with FEATURE_CHROMATIC; the power series stay grey, one value for all channels)
 * Twin of volmc/reference/estimators.py (the two families, the per-segment driver and the
 * exact treatment of homogeneous segments are described there); the registry of names is
 * volmc/techniques.py. The power series (power_series.h) are compiled in only with
 * -DVOLMC_POWER_SERIES, the telescoping and jackknife estimators (debiasing.h) only with
 * -DVOLMC_DEBIASING: the build options their registry records carry. */
#ifndef VOLMC_ESTIMATORS_H
#define VOLMC_ESTIMATORS_H

#include "params.h"
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

static inline spec biased_raymarch_segment(const MediumData *med, float3 o, float3 d, float t0,
                                           float t1, float mbar, float mu_c, Rng *rng,
                                           ulong *counters, int max_steps) {
    float L = fmax(t1 - t0, 0.0f);
    if (mbar <= 0.0f || L <= 0.0f) return 1.0f;
    int n = max(1, (int)ceil(RAYMARCH_SAMPLES_PER_MFP * mbar * L));
    if (n > max_steps) {
        counters[C_CAPPED] += 1;
        n = max_steps;
    }
    return exp(-(medium_chroma(med) *
                 optical_depth_comb(med, o, d, t0, L, n, rng_next(rng), mbar, counters)));
}

static inline spec segment_estimate(int kind, const MediumData *med, float3 o, float3 d, float t0,
                                    float t1, float s_maj, float s_min, Rng *rng, ulong *counters,
                                    int max_steps) {
    if (kind == SEGMENT_BIASED_RAYMARCH)
        return biased_raymarch_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters,
                                       max_steps);
#ifdef VOLMC_POWER_SERIES
    if (kind == SEGMENT_POWER_SERIES)
        return (spec)(power_series_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters,
                                           max_steps));
    if (kind == SEGMENT_UNBIASED_RAYMARCH)
        return (spec)(unbiased_raymarch_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters,
                                                max_steps));
#endif
#ifdef VOLMC_DEBIASING
    if (kind == SEGMENT_TELESCOPING)
        return telescoping_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters, max_steps);
    if (kind == SEGMENT_JACKKNIFE)
        return jackknife_segment(med, o, d, t0, t1, s_maj, s_min, rng, counters, max_steps);
#endif
    return exp(-(medium_chroma(med) * (s_maj * (t1 - t0)))); /* SEGMENT_ANALYTIC */
}

/* RGB in chromatic builds, with transmittance roulette on the largest channel (spec_roulette). */
static inline spec transmittance_by_segments(const MediumData *med, float3 o, float3 d, float t0,
                                             float t1, int kind, Rng *rng, ulong *counters,
                                             int max_steps) {
    o = o + t0 * d;
    MajorantIter it;
    majorant_iter_init(&it, med, o, d, 0.0f, t1 - t0);
    spec k = medium_chroma(med);
    spec T = 1.0f;
    Segment seg;
    while (majorant_next(&it, med, &seg)) {
        if (!spec_roulette(&T, rng)) return T;
        if (seg.sigma_min == seg.sigma_maj) {
            T *= exp(-(k * (seg.sigma_maj * (seg.t_max - seg.t_min))));
            continue;
        }
        T *= segment_estimate(kind, med, o, d, seg.t_min, seg.t_max, seg.sigma_maj,
                              seg.sigma_min, rng, counters, max_steps);
    }
    return T;
}

#define TRANSMITTANCE_ARGS const MediumData *med, float3 o, float3 d, float t0, float t1, \
    Rng *rng, ulong *counters, int max_steps

static inline spec transmittance_analytic(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, SEGMENT_ANALYTIC, rng, counters,
                                     max_steps);
}

/* The tracking estimators return spec too. */
static inline spec tracked_transmittance(TRANSMITTANCE_ARGS, int technique) {
    float t;
    spec T;
    float3 E;
    track(med, o, d, t0, t1, technique, technique == TRACK_LENGTH || technique == TRACK_AUTO,
          (float3)(1.0f), -1, rng, counters, max_steps, &t, &T, &E);
    return T;
}

static inline spec transmittance_track_length(TRANSMITTANCE_ARGS) {
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps, TRACK_LENGTH);
}

static inline spec transmittance_ratio_tracking(TRANSMITTANCE_ARGS) {
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps, TRACK_RATIO);
}

static inline spec transmittance_residual_ratio(TRANSMITTANCE_ARGS) {
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps,
                                 TRACK_RESIDUAL_RATIO);
}

static inline spec transmittance_next_flight(TRANSMITTANCE_ARGS) {
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps,
                                 TRACK_NEXT_FLIGHT);
}

#if defined(VOLMC_POWER_SERIES) && defined(VOLMC_DEBIASING)
/* render.transmittance = "auto" (twins in estimators.py, which say why). */
static inline int auto_alone_kind(const MediumData *med) {
    return (FEATURE_CHROMATIC ? med->m.spectral != SPECTRAL_GREY : 0) ? SEGMENT_TELESCOPING
                                                                      : SEGMENT_UNBIASED_RAYMARCH;
}

static inline spec transmittance_auto(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, auto_alone_kind(med), rng, counters,
                                     max_steps);
}
#endif

static inline spec transmittance_auto_shadow(TRANSMITTANCE_ARGS) {
    return tracked_transmittance(med, o, d, t0, t1, rng, counters, max_steps, TRACK_AUTO);
}

static inline spec transmittance_biased_raymarch(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, SEGMENT_BIASED_RAYMARCH, rng,
                                     counters, max_steps);
}

#ifdef VOLMC_POWER_SERIES
static inline spec transmittance_power_series(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, SEGMENT_POWER_SERIES, rng, counters,
                                     max_steps);
}

static inline spec transmittance_unbiased_raymarch(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, SEGMENT_UNBIASED_RAYMARCH, rng,
                                     counters, max_steps);
}
#endif

#ifdef VOLMC_DEBIASING
static inline spec transmittance_telescoping(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, SEGMENT_TELESCOPING, rng, counters,
                                     max_steps);
}

static inline spec transmittance_jackknife(TRANSMITTANCE_ARGS) {
    return transmittance_by_segments(med, o, d, t0, t1, SEGMENT_JACKKNIFE, rng, counters,
                                     max_steps);
}
#endif

#endif
