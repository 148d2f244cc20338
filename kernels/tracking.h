/* The tracking loop, written once: tentative collisions over the medium's majorant segments
 * and what each technique (TRACK_*) does at them. Twin of volmc/reference/tracking.py, where
 * the techniques, the carried optical-depth budget, the exact treatment of homogeneous
 * segments and the guards (local distances, step cap, transmittance roulette) are described.
 *
 * Per lane, a walk does exactly what the reference's nested loops do (segments, and tentative
 * collisions within a segment), with the same random numbers. The lanes run one flat loop
 * instead: a walk is a record (Walk) and walk_step advances every live lane by one event --
 * the start of its next segment, or one tentative collision -- so a lane that crosses many
 * cell faces does not hold the others in an inner loop. Each lane carries its own technique,
 * so one loop can advance free flights and shadow rays side by side (the integrator's
 * lanes do); `may`, a constant bit set of the techniques a call site can meet, lets the
 * compiler drop the code of the others. track() is one walk run to its end, the twin of
 * the reference's track. */
#ifndef VOLMC_TRACKING_H
#define VOLMC_TRACKING_H

#include "params.h"
#include "lanes.h"
#include "rng.h"
#include "sampling.h"
#include "medium.h"
#include "emitters.h"

/* Guard "transmittance roulette": returns the lanes of `active` whose walk goes on (T is 0 in
 * those that end). */
static inline lmask transmittance_roulette(lfloat *T, Rng *rng, lmask active) {
    lfloat a = fabs(*T);
    lmask low = active & (a < TR_RR_THRESHOLD);
    if (!ANY(low)) return active;
    lmask draw = low & (a != 0.0f);
    lfloat u = rng_next(rng, draw);
    lmask end = (low & (a == 0.0f)) | (draw & (u * TR_RR_THRESHOLD >= a));
    *T = select(*T, (lfloat)(0.0f), end);
    *T = select(*T, select((lfloat)(-TR_RR_THRESHOLD), (lfloat)(TR_RR_THRESHOLD), *T > 0.0f),
                low & !end);
    return active & !end;
}

/* Guard "transmittance roulette" on a spec weight (twin of spec_roulette in tracking.py):
 * by its largest |component|; grey builds play the scalar roulette. */
static inline lmask spec_roulette(spec *T, Rng *rng, lmask active) {
#if FEATURE_CHROMATIC
    lfloat a = spec_max(spec_abs(*T));
    lmask low = active & (a < TR_RR_THRESHOLD);
    if (!ANY(low)) return active;
    lmask draw = low & (a != 0.0f);
    lfloat u = rng_next(rng, draw);
    lmask end = (low & (a == 0.0f)) | (draw & (u * TR_RR_THRESHOLD >= a));
    *T = sel3(*T, v3s(0.0f), end);
    *T = sel3(*T, scale3(*T, TR_RR_THRESHOLD / a), low & !end);
    return active & !end;
#else
    return transmittance_roulette(T, rng, active);
#endif
}

/* What one tentative collision adds to the emission estimate (twin in tracking.py): with
 * several media, each emitting medium's sigma_a Le at p, from its own counted lookup. */
static inline lvec3 emission_term(const MediumData *med, lint media, lvec3 p, lfloat mu,
                                  lfloat s_maj, lvec3 W, lulong *counters, lmask active) {
    float3 k = (float3)(1.0f) * medium_chroma(med);
#if MEDIA_COUNT == 1
    float3 ka = (1.0f - vec3(med->m[0].albedo)) * k;
    lfloat s = mu / s_maj;
    lvec3 Le = emitted_radiance(med, 0, p, active);
    return v3(ka.x * s * Le.x * W.x, ka.y * s * Le.y * W.y, ka.z * s * Le.z * W.z);
#else
    lvec3 out = v3s(0.0f);
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        lmask on = has_medium(media, i, active);
        if (med->m[i].emission_kind == EMISSION_NONE || !ANY(on)) continue;
        float3 ka = (1.0f - vec3(med->m[i].albedo)) * k;
        lfloat s = medium_extinction(med, i, p, counters, on) / s_maj;
        lvec3 Le = emitted_radiance(med, i, p, on);
        out = add3(out, v3(ka.x * s * Le.x * W.x, ka.y * s * Le.y * W.y, ka.z * s * Le.z * W.z));
    }
    return out;
#endif
}

/* How a free flight weighs its emission against emission sampling (the reference's `emis`
 * tuple, tracking.py emission_weight): pdf < 0 in a lane: weight 1; else the density its
 * direction was sampled with (0: emission sampling alone), the vertex `shift` before the
 * walk's origin (walk_begin: from the ray's, as given); n emitter samples per vertex;
 * heuristic render.mis. */
typedef struct {
    lfloat pdf, shift;
    float n;
    int heuristic;
} EmisMis;

static inline EmisMis emis_plain(void) {
    EmisMis e = {(lfloat)(-1.0f), (lfloat)(0.0f), 0.0f, 0};
    return e;
}

/* The MIS weight of a tentative collision's emission at p (twin in tracking.py, which
 * derives it), in the active lanes (1 in the others): s_maj the majorant there, dist the
 * distance from the vertex. */
static inline lfloat emission_weight(const EmisMis *emis, const MediumData *med, lvec3 p,
                                     lfloat s_maj, lfloat dist, lmask active) {
    lmask weigh = active & (emis->pdf >= 0.0f);
    if (!ANY(weigh)) return (lfloat)(1.0f);
    lfloat pl = emis->n * emitter_pdf(med, p, weigh);
    /* Both densities times dist^2 (tracking.py) */
    lfloat w = mis_weight(emis->heuristic, emis->pdf * s_maj, pl * dist * dist);
    w = select(w, (lfloat)(0.0f), emis->pdf == 0.0f); /* "light": even where pl dist^2 is 0 */
    return select((lfloat)(1.0f), w, weigh & (pl > 0.0f));
}

/* Hero MIS: balance-heuristic weights R / mean(R) (twin in tracking.py). */
static inline lvec3 mis_weights(lvec3 R) {
    lfloat s = (R.x + R.y + R.z) / 3.0f;
    return sel3(v3s(0.0f), div3(R, s), s > 0.0f);
}

#if FEATURE_CHROMATIC
/* Spectral tracking's choice at a tentative collision (twin in tracking.py): returns the
 * lanes where it is real; writes the weight factor. */
static inline lmask spectral_choice(lvec3 W, float3 k, lfloat mu, lfloat s_maj, lfloat u,
                                    lvec3 *f) {
    lfloat a = fmax(W.x * k.x * mu, fmax(W.y * k.y * mu, W.z * k.z * mu));
    lvec3 n = v3(s_maj - k.x * mu, s_maj - k.y * mu, s_maj - k.z * mu);
    lfloat b = max3(mul3(W, n));
    lmask none = !(a + b > 0.0f);
    lmask real = !none & (u * (a + b) < a);
    *f = sel3(scale3(n, (a + b) / (s_maj * b)), scale3(v3u(k), mu * (a + b) / (s_maj * a)),
              real);
    *f = sel3(*f, v3s(0.0f), none);
    return real;
}
#endif

/* render.transmittance = "auto": the technique for one majorant segment of extinction bounds
 * [s_min, s_maj] and length L (twin in tracking.py, where the rule and its measurements are). */
static inline lint auto_segment_technique(lfloat s_maj, lfloat s_min, lfloat L) {
    return select((lint)(TRACK_LENGTH), (lint)(TRACK_RESIDUAL_RATIO),
                  (s_maj - s_min) * L <= AUTO_THIN_DEPTH);
}

/* A walk per lane: its ray, its technique, where it is, and what it has found. */
typedef struct {
    lvec3 o, d;       /* the ray, its origin moved to t0 (guard "local distances") */
    lfloat t0, t1;    /* the segment of the original ray the walk covers */
    lint tech;        /* TRACK_*: what the walk is */
    lmask use_control; /* free flight and track length: the segment's minorant as control */
    lvec3 beta;       /* free flight: the path's throughput (hero: its ratios) */
    lint hero;        /* free flight: the hero channel, or -1 */
    EmisMis emis;     /* free flight: its emission's weight against emission sampling */
    MajorantIter it;  /* the majorant segments */
    /* The current segment, the technique for it, and the walk's place in it */
    lfloat tb, s_maj, control, rate, inv_rate;
#if MEDIA_COUNT > 1
    lint media;       /* the media the segment's lookups read (WALK_MEDIA) */
#endif
    lmask in_seg, homogeneous, flight;
    lfloat t;         /* distance from o */
    lfloat budget;    /* optical depth left to the next tentative collision; < 0: not drawn */
    lint steps;
    spec w, acc;      /* next flight: the current vertex's weight, this segment's estimate */
    /* The outcome: T is the transmittance estimate or the flight's weight, E the emission
     * gathered per unit beta (free flight); event and t_end are final once the lane is no
     * longer live. */
    spec T;
    lvec3 E;
    lint event;
    lfloat t_end;
    lmask live;
} Walk;

/* The media the current segment's lookups read. One medium's build keeps no such field: with
 * a store per segment it never read, `volmc bench render --baseline` put the code before
 * the field at 0.97x and 0.98x of the default cloud's time, without it at 1.01x and 1.06x. */
#if MEDIA_COUNT > 1
#define WALK_MEDIA(wk) ((wk)->media)
#else
#define WALK_MEDIA(wk) ((lint)(1))
#endif

/* Bit of technique X in a `may` set. */
#define TRACK_BIT(X) (1 << (X))
#define TRACK_ANY 0x3F

/* Starts a walk of o + t d over [t0, t1] in the active lanes, with technique tech (per lane)
 * and, for free flight and track length, use_control (decomposition tracking: the minorant
 * decides where it covers the majorant); near: media_near of the segment (or a superset, as
 * enter_media_near gives it for the whole ray). Forced inline, as enter_media_near is
 * (integrator.cl): PoCL kept both out of line, and with them inlined into the stages the
 * default cloud reaches equal error in 1/1.06 of the time at W = 16 (Intel Xeon, AVX-512),
 * the scan, plume and fire in 1/1.03, and W = 1 in the same time (the same bits). */
static inline __attribute__((always_inline)) void walk_begin(Walk *wk, const MediumData *med,
        lvec3 o, lvec3 d, lfloat t0, lfloat t1, lint near, lint tech, lmask use_control,
        lvec3 beta, lint hero, EmisMis emis, lmask active) {
    wk->o = sel3(wk->o, madd3(o, d, t0), active);
    wk->d = sel3(wk->d, d, active);
    wk->t0 = select(wk->t0, t0, active);
    wk->t1 = select(wk->t1, t1, active);
    wk->tech = select(wk->tech, tech, active);
    wk->use_control = select(wk->use_control, use_control, active);
    wk->beta = sel3(wk->beta, beta, active);
    wk->hero = select(wk->hero, hero, active);
    if (FEATURE_EMISSION) { /* (a build without emission carries none of it) */
        wk->emis.pdf = select(wk->emis.pdf, emis.pdf, active);
        wk->emis.shift = select(wk->emis.shift, emis.shift + t0, active); /* from the origin */
        if (emis.n > 0.0f) { /* the same for every weighed walk of a launch; a plain walk (a
                              * shadow ray beside the lanes' flights) must not clear them */
            wk->emis.n = emis.n;
            wk->emis.heuristic = emis.heuristic;
        }
    }
    majorant_iter_init_near(&wk->it, med, wk->o, d, (lfloat)(0.0f), t1 - t0, near, active);
    wk->in_seg = wk->in_seg & !active;
    wk->budget = select(wk->budget, (lfloat)(-1.0f), active);
    wk->steps = select(wk->steps, (lint)(0), active);
    wk->T = spec_sel(wk->T, spec_s((lfloat)(1.0f)), active);
    wk->E = sel3(wk->E, v3s(0.0f), active);
    wk->event = select(wk->event, (lint)(EVENT_ESCAPE), active);
    wk->t_end = select(wk->t_end, t1, active);
    wk->live = wk->live | active;
}

/* Out of line: it costs nothing measurable on PoCL, and the AMDGPU compiler (LLVM 19) took
 * 175 s for a render kernel with it inlined against 7 s (its "SI Fix SGPR copies" pass grows
 * with the size of a function). */
#ifndef WALK_STEP_ATTR
#define WALK_STEP_ATTR __attribute__((noinline))
#endif

/* One event of every live walk: the start of its next segment (or the walk's end when none
 * is left), or its next tentative collision. Returns the lanes whose walk ended. */
static inline WALK_STEP_ATTR lmask walk_step(Walk *wk, const MediumData *med,
                                                             int may, Rng *rng,
                                                             lulong *counters, int max_steps) {
    /* Plain constants 0 in builds without the feature: they lead any condition they join,
     * since clang warns of a logical operator whose right operand is constant. */
    const int spectral = FEATURE_CHROMATIC ? med->m[0].spectral != SPECTRAL_GREY : 0;
    const int emissive = FEATURE_EMISSION ? (may & TRACK_BIT(TRACK_FREE_FLIGHT)) &&
                                                media_emit(med) : 0;
    const int may_fly = may & (TRACK_BIT(TRACK_FREE_FLIGHT) | TRACK_BIT(TRACK_LENGTH) |
                               TRACK_BIT(TRACK_AUTO));
    const int may_ratio = may & (TRACK_BIT(TRACK_RATIO) | TRACK_BIT(TRACK_RESIDUAL_RATIO) |
                                 TRACK_BIT(TRACK_AUTO));
    const uspec k = medium_chroma(med);
    /* The lanes of each technique (0 for those the call site cannot meet). */
    const lmask ff = lanes_if(may & TRACK_BIT(TRACK_FREE_FLIGHT)) & (wk->tech == TRACK_FREE_FLIGHT);
    const lmask length = lanes_if(may & TRACK_BIT(TRACK_LENGTH)) & (wk->tech == TRACK_LENGTH);
    const lmask next = lanes_if(may & TRACK_BIT(TRACK_NEXT_FLIGHT)) &
                       (wk->tech == TRACK_NEXT_FLIGHT);
    const lmask autos = lanes_if(may & TRACK_BIT(TRACK_AUTO)) & (wk->tech == TRACK_AUTO);
    const lmask live0 = wk->live;
    counters[C_LANE_ROUNDS] += lane_ones(LANE_IOTA == 0);
    counters[C_LANE_ACTIVE] += lane_ones(live0);
    /* Lanes between segments start their next one (or end: no segment left). */
    lmask need = wk->live & !wk->in_seg;
    if (ANY(need)) {
        Segment seg = {0}; /* written in the lanes that get a segment, read only there */
        lmask ok = majorant_next(&wk->it, med, &seg, need);
        wk->live = wk->live & !(need & !ok);
        lfloat ta = seg.t_min, sm = seg.sigma_maj, smin = seg.sigma_min;
        lfloat L = seg.t_max - ta;
        lmask hom = smin == sm;
        /* This segment's technique: the walk's own, or auto's choice for it. */
        lint tech = ANY(autos) ? select(wk->tech, auto_segment_technique(sm, smin, L), autos)
                               : wk->tech;
        lmask fl = tech == TRACK_FREE_FLIGHT || tech == TRACK_LENGTH;
        lmask res = tech == TRACK_RESIDUAL_RATIO;
        /* Roulette on the product so far before spending work on another segment (a no-op
         * while T >= TR_RR_THRESHOLD, so on the first segment). Grey track length keeps its
         * estimate 0 or 1: a fraction left by homogeneous segments goes on with probability T
         * as 1 (tracking.py). */
        if (!spectral && (may & TRACK_BIT(TRACK_LENGTH))) {
            lmask frac = ok & length & (spec_first(wk->T) < 1.0f);
            if (ANY(frac)) {
                lmask end = frac & (rng_next(rng, frac) >= spec_first(wk->T));
                wk->T = spec_sel(wk->T, spec_s(select((lfloat)(1.0f), (lfloat)(0.0f), end)),
                                 frac);
                wk->live = wk->live & !end;
                ok = ok & !end;
            }
        }
        if (may & ~TRACK_BIT(TRACK_FREE_FLIGHT)) {
            lmask tr = ok & !ff;
            lmask go_on = spec_roulette(&wk->T, rng, tr);
            wk->live = wk->live & !(tr & !go_on);
            ok = ok & !(tr & !go_on);
            /* Homogeneous segments are exact; the lane goes on to its next one. */
            lmask exact = ok & !ff & hom;
            wk->T = spec_sel(wk->T, spec_mul(wk->T, spec_exp_neg(k, sm * L)), exact);
            ok = ok & !exact;
        }
        lfloat ctl = select((lfloat)(0.0f), smin, hom | res | (fl & wk->use_control));
        lfloat rt = select(sm, sm - ctl, res);
        if (may_ratio)
            wk->T = spec_sel(wk->T, spec_mul(wk->T, spec_exp_neg(k, ctl * L)), ok & res);
        if (may & TRACK_BIT(TRACK_NEXT_FLIGHT)) {
            wk->w = spec_sel(wk->w, spec_s((lfloat)(1.0f)), ok & next);
            wk->acc = spec_sel(wk->acc, spec_s(exp(-sm * L)), ok & next);
        }
        wk->t = select(wk->t, ta, ok);
        wk->tb = select(wk->tb, seg.t_max, ok);
        wk->s_maj = select(wk->s_maj, sm, ok);
#if MEDIA_COUNT > 1
        wk->media = select(wk->media, seg.media, ok);
#endif
        wk->control = select(wk->control, ctl, ok);
        wk->rate = select(wk->rate, rt, ok);
        wk->inv_rate = select(wk->inv_rate, 1.0f / rt, ok); /* a multiplication per step */
        wk->homogeneous = select(wk->homogeneous, hom, ok);
        wk->flight = select(wk->flight, fl, ok);
        lmask draw = ok & (wk->budget < 0.0f);
        if (ANY(draw)) {
            lfloat pdf;
            wk->budget = select(wk->budget,
                                sample_exponential(rng_next(rng, draw), (lfloat)(1.0f), &pdf),
                                draw);
        }
        wk->in_seg = wk->in_seg | ok;
    }
    /* Lanes inside a segment: the next tentative collision, or the segment's end. */
    lmask in = wk->live & wk->in_seg;
    if (!ANY(in)) return live0 & !wk->live;
    lfloat t = wk->t, s_maj = wk->s_maj, control = wk->control;
    lfloat step = wk->budget * wk->inv_rate;
    lmask cross = in & (t + step >= wk->tb);
    /* >= 0: rounding must not turn what is left into the "not drawn" marker */
    wk->budget = select(wk->budget, fmax(wk->budget - wk->rate * (wk->tb - t), 0.0f), cross);
    wk->in_seg = wk->in_seg & !cross;
    if (may & TRACK_BIT(TRACK_NEXT_FLIGHT))
        wk->T = spec_sel(wk->T, spec_mul(wk->T, wk->acc), cross & next);
    lmask col = in & !cross;
    if (!ANY(col)) return live0 & !wk->live;
    t = select(t, t + step, col);
    wk->t = t;
    lvec3 p = madd3(wk->o, wk->d, t);
    spec T = wk->T;
    /* Lanes whose walk ends here, and those that go on to the next tentative collision. */
    lmask scatter = (lmask)(0), end = (lmask)(0), go_on = col;
#if FEATURE_CHROMATIC
    if (spectral && may_fly && ANY(col & wk->flight)) {
        lmask fly = col & wk->flight;
        /* Spectral tracking: the density of a homogeneous segment needs no lookup. */
        lfloat mu = select(extinction_in(med, WALK_MEDIA(wk), p, s_maj, counters,
                                         fly & !wk->homogeneous),
                           s_maj, wk->homogeneous);
        /* The hero's one-hot weights: its delta tracking decides (tracking.py). */
        lmask heroic = ff & (wk->hero >= 0);
        lvec3 hot = v3(select((lfloat)(0.0f), (lfloat)(1.0f), wk->hero == 0),
                       select((lfloat)(0.0f), (lfloat)(1.0f), wk->hero == 1),
                       select((lfloat)(0.0f), (lfloat)(1.0f), wk->hero == 2));
        lvec3 W = sel3(sel3(T, mul3(T, wk->beta), ff), hot, heroic);
        if (emissive) {
            lfloat we = emission_weight(&wk->emis, med, p, s_maj, wk->emis.shift + t, fly & ff);
            wk->E = sel3(wk->E,
                         add3(wk->E, emission_term(med, WALK_MEDIA(wk), p, mu, s_maj,
                                                   scale3(sel3(T, mis_weights(mul3(T, wk->beta)),
                                                               heroic), we),
                                                   counters, fly & ff)),
                         fly & ff);
        }
        lvec3 f;
        lmask real = fly & spectral_choice(W, k, mu, s_maj, rng_next(rng, fly), &f);
        /* Track length's estimate is 0 at a real collision (auto flies only as it). */
        T = sel3(T, sel3(v3s(0.0f), mul3(T, f), ff), real);
        scatter = scatter | real;
        lmask null = fly & !real;
        T = sel3(T, mul3(T, f), null);
        lmask dark = null & (max3(T) <= 0.0f);
        T = sel3(T, v3s(0.0f), dark);
        end = end | dark;
        /* Only the ratios matter to hero MIS: keep them from overflowing. */
        T = sel3(T, scale3(T, 1.0f / max3(T)), null & !dark & heroic);
        go_on = (go_on & !fly) | (null & !dark);
    }
#endif
    if (!spectral && may_fly && ANY(col & wk->flight)) {
        lmask fly = col & wk->flight;
        /* Real for sure where the control covers the majorant (no draw, no lookup). */
        lmask sure = fly & (control >= s_maj);
        lmask draw = fly & !sure;
        lfloat um = rng_next(rng, draw) * s_maj;
        lmask by_control = draw & (um < control);
        lmask look = draw & !by_control;
        lfloat mu = extinction_in(med, WALK_MEDIA(wk), p, s_maj, counters, look);
        lmask real = sure | by_control | (look & (um < mu));
        if (emissive && ANY(fly & ff)) {
            lmask glow = fly & ff;
            /* -1: not looked up */
            mu = select(select((lfloat)(-1.0f), s_maj, sure), mu, look);
            lmask again = glow & (mu < 0.0f);
            mu = select(mu, extinction_in(med, WALK_MEDIA(wk), p, s_maj, counters, again), again);
            lfloat we = emission_weight(&wk->emis, med, p, s_maj, wk->emis.shift + t, glow);
            wk->E = sel3(wk->E,
                         add3(wk->E, emission_term(med, WALK_MEDIA(wk), p, mu, s_maj, v3s(we),
                                                   counters, glow)),
                         glow);
        }
        /* Free flight's weight stays 1; track length's estimate is 0 at a real collision. */
        T = spec_sel(T, spec_s(select((lfloat)(0.0f), (lfloat)(1.0f), ff)), real);
        scatter = scatter | real;
        go_on = go_on & !real;
    }
    if ((may & TRACK_BIT(TRACK_NEXT_FLIGHT)) && ANY(col & next)) {
        lmask nf = col & next;
        lfloat mu = extinction_in(med, WALK_MEDIA(wk), p, s_maj, counters, nf);
        spec w = spec_mul_one_minus(wk->w, k, mu / s_maj);
        lmask alive = spec_roulette(&w, rng, nf);
        wk->w = spec_sel(wk->w, w, nf);
        /* The rest of this segment adds nothing: its estimate is acc, and the next segment
         * draws afresh. */
        lmask stop = nf & !alive;
        wk->budget = select(wk->budget, (lfloat)(-1.0f), stop);
        wk->in_seg = wk->in_seg & !stop;
        T = spec_sel(T, spec_mul(T, wk->acc), stop);
        wk->acc = spec_sel(wk->acc, spec_add(wk->acc, spec_scale(w, exp(-s_maj * (wk->tb - t)))),
                           alive);
        go_on = go_on & !stop;
    }
    if (may_ratio && ANY(col & !wk->flight & !next)) {
        lmask ratio = col & !wk->flight & !next;
        lfloat mu = extinction_in(med, WALK_MEDIA(wk), p, s_maj, counters, ratio);
        T = spec_sel(T, spec_mul_one_minus(T, k, (mu - control) / wk->rate), ratio);
        lmask alive = spec_roulette(&T, rng, ratio);
        end = end | (ratio & !alive);
        go_on = go_on & !(ratio & !alive);
    }
    wk->event = select(wk->event, (lint)(EVENT_SCATTER), scatter);
    wk->t_end = select(wk->t_end, wk->t0 + t, scatter);
    wk->live = wk->live & !scatter & !end;
    /* The walk goes on: a new budget, and the step cap. */
    if (ANY(go_on)) {
        lfloat pdf;
        wk->budget = select(wk->budget, sample_exponential(rng_next(rng, go_on), (lfloat)(1.0f),
                                                           &pdf),
                            go_on);
        wk->steps = wk->steps + (go_on & 1);
        lmask capped = go_on & (wk->steps >= max_steps);
        if (ANY(capped)) {
            counters[C_CAPPED] += lane_ones(capped);
            if (may & TRACK_BIT(TRACK_NEXT_FLIGHT))
                T = spec_sel(T, spec_mul(T, wk->acc), capped & next);
            if (may & TRACK_BIT(TRACK_LENGTH))
                T = spec_sel(T, spec_s((lfloat)(0.0f)), capped & length);
            wk->event = select(wk->event, (lint)(EVENT_CAPPED), capped);
            wk->t_end = select(wk->t_end, wk->t0 + t, capped);
            wk->live = wk->live & !capped;
        }
    }
    wk->T = T;
    return live0 & !wk->live;
}

/* Walks o + t d over [t0, t1] in the active lanes with `technique`: walk_begin, then
 * walk_step until every lane's walk has ended. Returns the event per lane; writes the
 * distance (t1 on escape) to *t_out, the transmittance estimate or flight weight to *T_out
 * and the emission gathered (free flight, per unit beta) to *E_out. hero < 0 in a lane:
 * spectral tracking weighed by beta; hero = c: channel c decides, beta holds the ratios
 * (tracking.py). Always inlined: a call site with a constant technique keeps only its code. */
static inline __attribute__((always_inline)) lint track(
    const MediumData *med, lvec3 o, lvec3 d, lfloat t0, lfloat t1, int technique,
    int use_control, lvec3 beta, lint hero, EmisMis emis, Rng *rng, lulong *counters,
    int max_steps, lmask active, lfloat *t_out, spec *T_out, lvec3 *E_out) {
    Walk wk = {0};   /* records start defined in every lane (lanes.h) */
    walk_begin(&wk, med, o, d, t0, t1, media_near(med, o, d, t0, t1, active), (lint)(technique),
               lanes_if(use_control), beta, hero, emis, active);
    while (ANY(wk.live)) walk_step(&wk, med, TRACK_BIT(technique), rng, counters, max_steps);
    *t_out = wk.t_end;
    *T_out = wk.T;
    *E_out = wk.E;
    return wk.event;
}

#endif
