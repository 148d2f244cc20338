/* Volumetric path tracer kernel. Twin of volmc/reference/integrator.py: the algorithm, the order
 * of random numbers and the Russian-roulette policy are described there.
 *
 * Built for the scene: -DFEATURE_X=0/1 options (volmc/scene/features.py; features.h defaults
 * every one to 1) turn a code path off where the scene cannot take it; each is a plain constant
 * in an ordinary `if`, so the compiler drops the dead path. Only the switches `volmc bench
 * specialise` shows to pay are kept (docs/performance.md, "Specialisation"); a build with
 * every one on renders any scene. SHADOW_ESTIMATOR names the shadow-ray estimator (render.transmittance);
 * VIEW_ESTIMATOR, defined only where it differs ("auto"), the one for camera rays that cannot
 * scatter, whose transmittance is the sample. -DLANES=W sets the paths per work-item
 * (lanes.h): each lane traces exactly the path the scalar kernel (W = 1) traces for its
 * sample, with the same random numbers.
 * params.h (generated from volmc/params.py and volmc/constants.py) defines the records and
 * constants. */

#include "params.h"
#include "features.h"
#include "lanes.h"
#include "guards.h"
#include "rng.h"
#include "sampler.h"
#include "sampling.h"
#include "phase.h"
#include "medium.h"
#include "free_flight.h"
#include "estimators.h"
#include "camera.h"
#include "environment.h"
#include "lights.h"
#include "emitters.h"

/* Guard "entry re-basing" (robustness case 10, 11, 13): clips ray o + t d to the box and, when the
 * box is entered from outside (t_enter > 0), moves the origin to the entry point, snapped onto
 * the box (clamped into it, and exactly onto the entry face), and clips again from there.
 * Every later distance is then local to the box: no tracking loop accumulates a large t (a
 * far camera), the chord comes from nearby numbers (exact for a thin slab seen from afar),
 * and a dense medium is entered exactly at its face, never a rounding error inside it (which
 * would bury the path). Returns the origin to use; writes the local segment [*t0, *t1] (no
 * medium when *t1 <= *t0) and the distance *shift the origin moved along d. Twin of
 * enter_box in integrator.py. */
static inline lvec3 enter_box(lvec3 o, lvec3 d, float3 bmin, float3 bmax, lfloat *t0, lfloat *t1,
                              lfloat *shift) {
    lfloat te = ray_box(o, d, bmin, bmax, t1);
    lmask enter = te > 0.0f && *t1 > te;
    lfloat oa[3] = {o.x, o.y, o.z}, da[3] = {d.x, d.y, d.z};
    float lo[3] = {bmin.x, bmin.y, bmin.z}, hi[3] = {bmax.x, bmax.y, bmax.z};
    lfloat pa[3];
    lint entry = (lint)(0);
    lfloat best = (lfloat)(-FLT_MAX);
    LANE_UNROLL for (int a = 0; a < 3; ++a) {
        pa[a] = clamp(oa[a] + te * da[a], lo[a], hi[a]);
        lmask moving = da[a] != 0.0f;
        lfloat face = select((lfloat)(hi[a]), (lfloat)(lo[a]), da[a] > 0.0f);
        lfloat tin = (face - oa[a]) / select(da[a], (lfloat)(1.0f), !moving);
        lmask better = moving & (tin > best);
        best = select(best, tin, better);
        entry = select(entry, (lint)(a), better);
    }
    LANE_UNROLL for (int a = 0; a < 3; ++a)
        pa[a] = select(pa[a], select((lfloat)(hi[a]), (lfloat)(lo[a]), da[a] > 0.0f), entry == a);
    lvec3 p = v3(pa[0], pa[1], pa[2]);
    lfloat t1_in;
    ray_box(p, d, bmin, bmax, &t1_in);
    *t1 = select(*t1, t1_in, enter);
    *t0 = select(fmax(te, 0.0f), (lfloat)(0.0f), enter);
    *shift = select((lfloat)(0.0f), te, enter);
    return sel3(o, p, enter);
}

/* enter_box for the medium's box, in its own space (twin in integrator.py): the origin
 * returned is in the scene frame; a placed medium's moves along d to its entry point. */
static inline lvec3 enter_medium(const Medium *m, lvec3 o, lvec3 d, lfloat *t0, lfloat *t1,
                                 lfloat *shift) {
    if (!FEATURE_TRANSFORM || !m->transformed)
        return enter_box(o, d, vec3(m->bmin), vec3(m->bmax), t0, t1, shift);
    enter_box(to_medium(m, o), to_medium_dir(m, d), vec3(m->bmin), vec3(m->bmax), t0, t1,
              shift);
    return sel3(o, madd3(o, d, *shift), *shift > 0.0f);
}

/* enter_medium for the scene's media (twin in integrator.py): the segment of o + t d from
 * where it enters the first box it meets to where it leaves the last; the origin moves (and
 * snaps) onto the box it enters first. Writes the media the ray comes near (media_near,
 * for the walk that follows: majorant_iter_init_near). Forced inline: see walk_begin. */
static inline __attribute__((always_inline)) lvec3 enter_media_near(const MediumData *med,
        lvec3 o, lvec3 d, lfloat *t0, lfloat *t1, lfloat *shift, lint *near_out) {
#if MEDIA_COUNT == 1
    *near_out = (lint)(1);
    return enter_medium(&med->m[0], o, d, t0, t1, shift);
#else
    /* Each box's span on the ray, and the medium met first. */
    lfloat te[MEDIA_COUNT], tx[MEDIA_COUNT];
    lfloat first = (lfloat)(FLT_MAX);
    lint j = (lint)(-1);
    lint near = media_near(med, o, d, (lfloat)(0.0f), (lfloat)(FLT_MAX), LANES_ALL);
    *near_out = near;
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        const Medium *m = &med->m[i];
        if (!ANY(has_medium(near, i, LANES_ALL))) { /* missed in every lane */
            te[i] = (lfloat)(FLT_MAX);
            tx[i] = (lfloat)(-FLT_MAX);
            continue;
        }
        te[i] = ray_box(to_medium(m, o), to_medium_dir(m, d), vec3(m->bmin), vec3(m->bmax),
                        &tx[i]);
        lmask hit = (tx[i] > te[i]) & (tx[i] > 0.0f) & (te[i] < first);
        first = select(first, te[i], hit);
        j = select(j, (lint)(i), hit);
    }
    lvec3 out = o;
    *t0 = (lfloat)(0.0f);
    *t1 = (lfloat)(-FLT_MAX);
    *shift = (lfloat)(0.0f);
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        lmask here = j == i;
        if (!ANY(here)) continue;
        lfloat a, b, sh;
        lvec3 oi = enter_medium(&med->m[i], o, d, &a, &b, &sh);
        out = sel3(out, oi, here);
        *t0 = select(*t0, a, here);
        *shift = select(*shift, sh, here);
    }
    /* The last exit, from the moved origin. */
    for (int i = 0; i < MEDIA_COUNT; ++i)
        *t1 = select(*t1, fmax(*t1, tx[i] - *shift), (j >= 0) & (tx[i] > te[i]));
    return out;
#endif
}

static inline lvec3 enter_media(const MediumData *med, lvec3 o, lvec3 d, lfloat *t0,
                                lfloat *t1, lfloat *shift) {
    lint near;
    return enter_media_near(med, o, d, t0, t1, shift, &near);
}

/* x with the components where beta is 0 set to 0 (twin in integrator.py). */
static inline lvec3 keep_carried(lvec3 beta, lvec3 x) {
    return v3(select((lfloat)(0.0f), x.x, beta.x != 0.0f),
              select((lfloat)(0.0f), x.y, beta.y != 0.0f),
              select((lfloat)(0.0f), x.z, beta.z != 0.0f));
}

static inline spec shadow_transmittance(const Params *prm, const MediumData *med, lvec3 o,
                                        lvec3 d, lfloat t_max, int view, Rng *rng_s,
                                        lulong *counters, lmask active) {
    lfloat t0, t1, shift;
    o = enter_media(med, o, d, &t0, &t1, &shift);
    t1 = fmin(t1, t_max - shift);
    lmask go = active & (t1 > t0);
    if (!ANY(go)) return spec_s((lfloat)(1.0f));
    record_segment(med, o, d, t0, t1, RECORD_SHADOW, go);
    counters[C_SHADOW] += lane_ones(go);
    spec T;
#ifdef VIEW_ESTIMATOR
    if (view)
        T = VIEW_ESTIMATOR(med, o, d, t0, t1, rng_s, counters, prm->max_steps, go);
    else
#endif
        T = SHADOW_ESTIMATOR(med, o, d, t0, t1, rng_s, counters, prm->max_steps, go);
    return spec_sel(spec_s((lfloat)(1.0f)), T, go);
}

/* Where a path's uniforms come from (render.sampler): twins of bounce_pair, path_pair_u24,
 * path_u2 and path_u1 in integrator.py, which describe them. The bounce, and with it the
 * pair, differs between lanes; a lane past SAMPLER_BOUNCES draws from its stream. */
static inline lint bounce_pair(lint b, int offset) {
    return select(SAMPLER_FIRST_BOUNCE + b * SAMPLER_PAIRS_PER_BOUNCE + offset, (lint)(-1),
                  b >= SAMPLER_BOUNCES);
}

static inline LanePair path_pair_u24(const Params *prm, luint pix, luint s, lint pair, luint j,
                                     uint count) {
    return sampler_pair(prm->sampler, prm->seed_lo, prm->seed_hi, pix, s * count + j,
                        as_luint(pair), prm->spp * count);
}

static inline lvec2 path_u2(const Params *prm, luint pix, luint s, lint pair, luint j,
                            uint count, Rng *rng, lmask active) {
    lmask from_rng = active & (lanes_if(prm->sampler == SAMPLER_INDEPENDENT) | (pair < 0));
    lvec2 u;
    u.x = rng_next(rng, from_rng);
    u.y = rng_next(rng, from_rng);
    lmask from_sampler = active & !from_rng;
    if (ANY(from_sampler)) {
        LanePair a = path_pair_u24(prm, pix, s, select(pair, (lint)(0), pair < 0), j, count);
        u.x = select(u.x, to_lfloat(a.x) * UNIFORM_SCALE, from_sampler);
        u.y = select(u.y, to_lfloat(a.y) * UNIFORM_SCALE, from_sampler);
    }
    return u;
}

static inline lfloat path_u1(const Params *prm, luint pix, luint s, lint pair, int axis,
                             luint j, uint count, Rng *rng, lmask active) {
    lmask from_rng = active & (lanes_if(prm->sampler == SAMPLER_INDEPENDENT) | (pair < 0));
    lfloat u = rng_next(rng, from_rng);
    lmask from_sampler = active & !from_rng;
    if (ANY(from_sampler)) {
        LanePair a = path_pair_u24(prm, pix, s, select(pair, (lint)(0), pair < 0), j, count);
        u = select(u, to_lfloat(axis == 1 ? a.y : a.x) * UNIFORM_SCALE, from_sampler);
    }
    return u;
}

/* EQUIANGULAR_OFF, _ALONE or _MIS (volmc/constants.py) for the scene. */
static inline int equiangular_mode(const Params *prm, const MediumData *med) {
    if (!prm->equiangular) return EQUIANGULAR_OFF;
    const Medium *m = &med->m[0];
    return MEDIA_COUNT == 1 && m->density_kind == DENSITY_CONSTANT &&
                   m->spectral == SPECTRAL_GREY
               ? EQUIANGULAR_MIS
               : EQUIANGULAR_ALONE;
}

/* Returns the unit direction from p to c, writes the distance (0 when p = c). */
static inline lvec3 direction_to(lvec3 p, lvec3 c, lfloat *dist) {
    lvec3 v = sub3(c, p);
    *dist = sqrt(dot3(v, v));
    return sel3(v, div3(v, *dist), *dist > 0.0f);
}

/* Returns the ray parameter h of c's foot on the ray o + t d, writes c's distance D from the
 * ray's line. */
static inline lfloat foot_on_ray(float3 c, lvec3 o, lvec3 d, lfloat *D) {
    lvec3 v = sub3(v3u(c), o);
    lfloat h = dot3(v, d);
    lvec3 w = sub3(v, scale3(d, h));
    *D = sqrt(dot3(w, w));
    return h;
}

/* sigma e^{-sigma (t - t0)}: free flight's collision density in a homogeneous grey medium. */
static inline lfloat free_flight_pdf(const Medium *m, lfloat t0, lfloat t) {
    float s = m->scale * m->density;
    return s * exp(-s * (t - t0));
}

/* MIS weight of next-event estimation towards point light c (twin in integrator.py). */
static inline lfloat point_light_nee_weight(const Params *prm, const Medium *m, int ea, float3 c,
                                            lvec3 o, lvec3 d, lfloat t0, lfloat t1, lfloat t) {
    if (ea == EQUIANGULAR_OFF) return (lfloat)(1.0f);
    lfloat D;
    lfloat h = foot_on_ray(c, o, d, &D);
    lfloat w = ea == EQUIANGULAR_ALONE
                   ? (lfloat)(0.0f)
                   : mis_weight(prm->mis, free_flight_pdf(m, t0, t),
                                equiangular_pdf(t, h, D, t0, t1));
    return select((lfloat)(1.0f), w, D > 0.0f);
}

/* rgb * s per lane, for a spec s (RGB, or one value for all channels). */
static inline lvec3 rgb_times(float3 rgb, spec s) { return mul3(v3u(rgb), spec_rgb(s)); }

/* The ray of next-event estimation towards delta light lt (parallel, point or spot) from
 * p = o + t d: returns the unit direction; writes the distance (NO_LIMIT for a directional
 * light) and the falloff (1, or a point light's MIS weight over the squared distance times a
 * spot's falloff; 0: this light sends nothing to p). Twin of light_ray in integrator.py. */
static inline lvec3 light_ray(const Params *prm, const Medium *m, int ea,
                              global const Light *lt, lvec3 o, lvec3 d, lfloat t0, lfloat t1,
                              lfloat t, lfloat *dist, lfloat *falloff) {
    float3 c = vec3g(lt->vec);
    if (lt->type == LIGHT_DIRECTIONAL) {
        *dist = (lfloat)(NO_LIMIT);
        *falloff = (lfloat)(1.0f);
        return v3u(-c);
    }
    lvec3 wl = direction_to(madd3(o, d, t), v3u(c), dist);
    lfloat f = point_light_nee_weight(prm, m, ea, c, o, d, t0, t1, t) / (*dist * *dist);
    if (lt->type == LIGHT_SPOT) f = f * spot_falloff(lt, wl);
    *falloff = select((lfloat)(0.0f), f, *dist > 0.0f);
    return wl;
}

/* The index for path_u2 of sample j of light i (n_lights: the environment); writes the
 * count (twin of light_point in integrator.py, which gives the layout). */
static inline luint light_point(const Params *prm, int i, luint j, uint *count) {
    uint n = (uint)prm->light_samples;
    if (prm->area_lights == 0) {
        *count = n;
        return j;
    }
    *count = (uint)(prm->n_lights + 1) * n;
    return (uint)i * n + j;
}

/* Lanes whose ray from p along w meets a sphere light other than target before dist. */
static inline lmask occluded(const Params *prm, global const Light *lights, lvec3 p, lvec3 w,
                             lfloat dist, lint target) {
    if (!prm->spheres) return (lmask)(0);
    lint i;
    lfloat t = nearest_sphere(prm, lights, p, w, &i);
    return (i >= 0) & (i != target) & (t < dist);
}

/* Weight of light found by a ray that light sampling could also have found (twin in
 * integrator.py). */
static inline lfloat escape_weight(const Params *prm, lint depth, lfloat pdf_phase,
                                   lfloat n_pdf_light) {
    return select((lfloat)(prm->transparent ? 0.0f : 1.0f),
                  mis_weight(prm->mis, pdf_phase, n_pdf_light), depth > 0);
}

/* The albedo of medium i (per lane: the medium each lane scattered in), RGB. */
static inline lvec3 medium_albedo(const MediumData *med, lint i) {
#if MEDIA_COUNT == 1
    return v3u(vec3(med->m[0].albedo));
#else
    lvec3 a = v3s(0.0f);
    for (int k = 0; k < MEDIA_COUNT; ++k) a = sel3(a, v3u(vec3(med->m[k].albedo)), i == k);
    return a;
#endif
}

/* Medium i's phase function between the path's direction d and w (per lane). */
static inline lfloat medium_phase_eval(const MediumData *med, lint i, lvec3 d, lvec3 w) {
#if MEDIA_COUNT == 1
    return phase_eval(med->m[0].phase_kind, med->m[0].g, d, w);
#else
    lfloat f = (lfloat)(0.0f);
    for (int k = 0; k < MEDIA_COUNT; ++k) {
        lmask at = i == k;
        if (ANY(at)) f = select(f, phase_eval(med->m[k].phase_kind, med->m[k].g, d, w), at);
    }
    return f;
#endif
}

/* A direction from medium i's phase function about d_in (per lane); writes its pdf. */
static inline lvec3 medium_phase_sample(const MediumData *med, lint i, lfloat u1, lfloat u2,
                                        lvec3 d_in, lfloat *pdf) {
#if MEDIA_COUNT == 1
    return phase_sample(med->m[0].phase_kind, med->m[0].g, u1, u2, d_in, pdf);
#else
    lvec3 w = d_in;
    for (int k = 0; k < MEDIA_COUNT; ++k) {
        lmask at = i == k;
        if (!ANY(at)) continue;
        lfloat pi;
        lvec3 wi = phase_sample(med->m[k].phase_kind, med->m[k].g, u1, u2, d_in, &pi);
        w = sel3(w, wi, at);
        *pdf = select(*pdf, pi, at);
    }
    return w;
#endif
}

/* Light scattered at p from the ray's direction d into w by every medium there: the sum
 * of sigma_s f(d, w), RGB, with a counted lookup per medium present (twin in
 * integrator.py). */
static inline lvec3 in_scattering(const MediumData *med, lvec3 p, lvec3 d, lvec3 w,
                                  lulong *counters, lmask active) {
    float3 k = (float3)(1.0f) * medium_chroma(med);
    lvec3 out = v3s(0.0f);
    lint here = media_at(med, p, active);
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        const Medium *m = &med->m[i];
        lmask on = has_medium(here, i, active);
        if (!ANY(on)) continue;
        lfloat mu = medium_extinction(med, i, p, counters, on);
        lfloat f = phase_eval(m->phase_kind, m->g, d, w);
        float3 a = vec3(m->albedo);
        out = add3(out, v3(a.x * (k.x * mu) * f, a.y * (k.y * mu) * f, a.z * (k.z * mu) * f));
    }
    return out;
}

/* Light from every point light scattered once inside [t0, t1] of the ray o + t d, by
 * equiangular sampling (twin of sample_equiangular_lights in integrator.py, which derives
 * it). */
static inline lvec3 sample_equiangular_lights(const Params *prm, global const Light *lights,
                                              const MediumData *med, int ea, lvec3 o, lvec3 d,
                                              lfloat t0, lfloat t1, luint pix, luint s, lint b,
                                              Rng *rng, Rng *rng_s, lulong *counters,
                                              lmask active) {
    const Medium *m = &med->m[0];
    lvec3 L = v3s(0.0f);
    for (int i = 0; i < prm->n_lights; ++i) {
        if (lights[i].type != LIGHT_POINT && lights[i].type != LIGHT_SPOT) continue;
        lfloat u = path_u1(prm, pix, s, bounce_pair(b, SAMPLER_EQUIANGULAR), 0, (luint)(i),
                           (uint)prm->n_lights, rng, active);
        float3 c = vec3g(lights[i].vec);
        lfloat D;
        lfloat h = foot_on_ray(c, o, d, &D);
        lmask ok = active & (D > 0.0f);
        lfloat pdf;
        lfloat t = sample_equiangular(u, h, D, t0, t1, &pdf);
        ok = ok & (pdf > 0.0f);
        lvec3 p = madd3(o, d, t);
        lfloat dist;
        lvec3 wl = direction_to(p, v3u(c), &dist);
        ok = ok & (dist > 0.0f);
        lfloat spot = lights[i].type == LIGHT_SPOT ? spot_falloff(&lights[i], wl)
                                                   : (lfloat)(1.0f);
        ok = ok & (spot > 0.0f) & !occluded(prm, lights, p, wl, dist, (lint)(-1));
        if (!ANY(ok)) continue;
#if MEDIA_COUNT == 1
        lfloat mu = extinction(med, p, (lfloat)(NO_LIMIT), counters, ok);
        float3 k = (float3)(1.0f) * medium_chroma(med), a = vec3(m->albedo);
        lvec3 sig_s = v3(a.x * (k.x * mu), a.y * (k.y * mu), a.z * (k.z * mu));
#else
        /* sigma_s times the phase function, summed over the media at p */
        lvec3 sig_s = in_scattering(med, p, d, wl, counters, ok);
#endif
        ok = ok & (max3(sig_s) > 0.0f);
        if (!ANY(ok)) continue;
        counters[C_SHADOW] += lane_ones(ok);
        spec t_cam = SHADOW_ESTIMATOR(med, o, d, t0, t, rng_s, counters, prm->max_steps, ok);
        spec t_lt = shadow_transmittance(prm, med, p, wl, dist, 0, rng_s, counters, ok);
        lfloat w = ea == EQUIANGULAR_MIS
                       ? mis_weight(prm->mis, pdf, free_flight_pdf(m, t0, t))
                       : (lfloat)(1.0f);
#if MEDIA_COUNT == 1
        lfloat f = phase_eval(m->phase_kind, m->g, d, wl) * w / (dist * dist * pdf);
#else
        lfloat f = w / (dist * dist * pdf);
#endif
        L = sel3(L,
                 add3(L, mul3(v3u(vec3g(lights[i].color)),
                              scale3(mul3(sig_s, spec_rgb(spec_mul(t_cam, t_lt))), f * spot))),
                 ok);
    }
    return L;
}

/* Russian roulette's survival probability (render.rr; twin in integrator.py): the cap is
   RR_MAX_SURVIVAL only where nothing else ends the path (max_depth = -1). */
static inline lfloat survival_probability(const Params *prm, lvec3 beta_w, lvec3 albedo) {
    lvec3 x = prm->rr == RR_ALBEDO ? mul3(beta_w, albedo) : beta_w;
    return fmin(max3(x), prm->max_depth < 0 ? RR_MAX_SURVIVAL : 1.0f);
}


/* ---- Lanes at work: the path of each lane, cut at its walks ------------------------------
 *
 * trace_path in integrator.py traces one path: free flights, and at every scattering vertex
 * next-event estimation with its shadow rays, then roulette and a phase-sampled direction.
 * Here each lane runs that same sequence, with the same random numbers, but the lanes are not
 * tied to one another between walks: every walk (a free flight or a shadow ray) is a lane of
 * one Walk record that walk_step advances for all lanes at once, and a lane whose walk ends
 * goes through the path logic below to its next walk -- or, when its path ends, writes its
 * sample and takes the work-item's next one (path regeneration). So lanes stay busy while
 * their paths differ in length and events. The functions below are this scheduling; the
 * algorithm they run is trace_path's, through the twins above. */

/* The stages below are kept out of line (STAGE), as walk_step is (tracking.h): on PoCL that
 * costs nothing measurable, and it keeps GPU compilers fast (AMDGPU's LLVM 19 took 7 s for
 * the inlined kernel at W = 1 against 1 s, and minutes at W > 1 against seconds). */
#ifndef STAGE
#define STAGE __attribute__((noinline))
#endif

/* What a lane is doing (kernel-only: the reference traces one path at a time). */
#define PATH_IDLE 0   /* no sample left for it */
#define PATH_START 1  /* a free flight is to begin */
#define PATH_FLIGHT 2 /* its free flight walks (or has just ended) */
#define PATH_NEE 3    /* next-event estimation: the next shadow ray is to be chosen */
#define PATH_SHADOW 4 /* a shadow ray walks (or has just ended) */
#define PATH_BOUNCE 5 /* next-event estimation done: roulette and a new direction */
#define PATH_DONE 6   /* the path has ended: its sample is to be written */

/* A path per lane: trace_path's variables, kept between walks. */
typedef struct {
    lint state;
    luint job, pix, s;       /* the sample: its job index in the launch, pixel and index */
    lvec3 o, d;              /* the current ray (its origin moved onto the box by enter_box) */
    lfloat t0, t1, t;        /* the flight's segment of it, and where it scattered */
    lvec3 L, beta, R, beta_w;
    lint hero, depth;
    lint medium;             /* the medium it scattered in last (several media) */
    lfloat pdf_phase;
    lint light, sample;      /* next-event estimation: light (n_lights: the environment) */
    lvec3 contrib;           /* what the pending shadow ray's transmittance adds to L */
    lfloat alpha;            /* coverage of the camera ray (trace_path) */
#if FEATURE_ALBEDO_AOV
    lvec3 aov;               /* the albedo AOV: the medium's albedo where it first scattered */
#endif
    lint hit;                /* the sphere light the flight's ray meets (-1: none) ... */
    lfloat pdf_hit;          /* ... and sample_sphere_light's pdf of that direction */
} Path;

/* A = 1 - T of a camera ray's transmittance estimate T (twin in integrator.py). */
static inline lfloat coverage(lvec3 T) { return 1.0f - (T.x + T.y + T.z) / 3.0f; }

/* The shadow-ray technique of the one walk loop, when the shadow estimator is a tracking
 * technique (SHADOW_TECHNIQUE, set by the host from techniques.py); the per-segment
 * estimators run their own loop at the moment the ray is chosen. */
#ifdef SHADOW_TECHNIQUE
#define WALK_TECHNIQUES (TRACK_BIT(TRACK_FREE_FLIGHT) | TRACK_BIT(SHADOW_TECHNIQUE))
/* The minorant as control, as tracked_transmittance gives it (estimators.h). */
#if SHADOW_TECHNIQUE == TRACK_LENGTH || SHADOW_TECHNIQUE == TRACK_AUTO
#define SHADOW_CONTROL 1
#else
#define SHADOW_CONTROL 0
#endif
#else
#define WALK_TECHNIQUES TRACK_BIT(TRACK_FREE_FLIGHT)
#endif

/* The environment's radiance from scene direction w: its map's (FEATURE_ENV_MAP) or the
 * constant prm->env (twin in integrator.py). */
static inline lvec3 env_light(const Params *prm, global const float *env, lvec3 w) {
    if (FEATURE_ENV_MAP && prm->env_map) return env_radiance(prm, env, w);
    return v3u(vec3(prm->env));
}

/* A direction for the environment's shadow rays, from the map's density or uniform over
 * the sphere (render.env_sampling); writes its pdf per steradian. */
static inline lvec3 sample_env_light(const Params *prm, global const float *env, lfloat u1,
                                     lfloat u2, lfloat *pdf, lmask active) {
    if (FEATURE_ENV_MAP && prm->env_map && prm->env_sampling == ENV_SAMPLING_IMPORTANCE)
        return sample_environment(prm, env, u1, u2, pdf, active);
    return sample_uniform_sphere(u1, u2, pdf);
}

/* Density per steradian of sample_env_light at scene direction w. */
static inline lfloat env_light_pdf(const Params *prm, global const float *env, lvec3 w) {
    if (FEATURE_ENV_MAP && prm->env_map && prm->env_sampling == ENV_SAMPLING_IMPORTANCE)
        return environment_pdf(prm, env, w);
    return (lfloat)(uniform_sphere_pdf());
}

/* Radiance a ray escaping along d sees in the sky: the environment and every sun disc whose
 * cone holds d, weighted by escape_weight (twin in integrator.py). */
static inline lvec3 escape_light(const Params *prm, global const Light *lights,
                                 global const float *env, lvec3 d, lfloat pdf_phase,
                                 lint depth) {
    const float n = (float)prm->light_samples;
    lvec3 L = v3s(0.0f);
    if (prm->has_env)
        L = scale3(env_light(prm, env, d),
                   escape_weight(prm, depth, pdf_phase, n * env_light_pdf(prm, env, d)));
    if (prm->area_lights > 0) {
        for (int i = 0; i < prm->n_lights; ++i) {
            global const Light *lt = &lights[i];
            if (lt->type != LIGHT_DIRECTIONAL || !(lt->size > 0.0f)) continue;
            lfloat pdf_l = cone_pdf(d, v3u(-vec3g(lt->vec)), (lfloat)(lt->size));
            lfloat w = escape_weight(prm, depth, pdf_phase, n * pdf_l) * sun_radiance(lt);
            L = sel3(L, add3(L, scale3(v3u(vec3g(lt->color)), w)), pdf_l > 0.0f);
        }
    }
    return L;
}

/* A new path in the lanes of `fresh`, for sample s of pixel pix: its camera ray, and the
 * channel of a colour path (trace_path's first steps). A scene that cannot scatter takes
 * its transmittance at once and is done. */
static inline STAGE void path_start(const Params *prm, global const Light *lights,
                                    global const float *env,
                                    MediumData *med, Path *path, ulong seed,
                              luint job, luint pix, luint s, Rng *rng, Rng *rng_s,
                              lulong *counters, lmask fresh) {
    const Medium *m = &med->m[0];
    path->job = select(path->job, job, fresh);
    path->pix = select(path->pix, pix, fresh);
    path->s = select(path->s, s, fresh);
    med->rec_pixel = select(med->rec_pixel, as_lint(pix), fresh);
    rng_init(rng, seed, pix, s, STREAM_PATH, fresh);
    rng_init(rng_s, seed, pix, s, STREAM_SHADOW, fresh);
    lint py = as_lint(pix / (uint)prm->width);
    lint px = as_lint(pix) - py * prm->width;
    lvec2 uc = path_u2(prm, pix, s, (lint)(SAMPLER_PAIR_PIXEL), (luint)(0u), 1u, rng, fresh);
    lvec2 ul = {(lfloat)(0.5f), (lfloat)(0.5f)}; /* a pinhole draws no lens sample */
    if (prm->aperture > 0.0f)
        ul = path_u2(prm, pix, s, (lint)(SAMPLER_PAIR_LENS), (luint)(0u), 1u, rng, fresh);
    lvec3 d;
    lvec3 o = camera_ray(prm, px, py, uc.x, uc.y, ul.x, ul.y, &d);
    path->o = sel3(path->o, o, fresh);
    path->d = sel3(path->d, d, fresh);
    path->L = sel3(path->L, v3s(0.0f), fresh);
    path->alpha = select(path->alpha, (lfloat)(0.0f), fresh);
#if FEATURE_ALBEDO_AOV
    path->aov = sel3(path->aov, v3s(0.0f), fresh);
#endif
    float top = 0.0f; /* the largest albedo of any medium */
    for (int i = 0; i < MEDIA_COUNT; ++i) {
        float3 albedo = vec3(med->m[i].albedo);
        top = fmax(top, fmax(albedo.x, fmax(albedo.y, albedo.z)));
    }
    const int emissive = FEATURE_EMISSION ? media_emit(med) : 0;
    if (!emissive && (prm->max_depth == 0 || top <= 0.0f)) {
        /* No scattering can contribute: environment times transmittance (see integrator.py). */
        lint hit = (lint)(-1);
        lfloat t_hit = prm->spheres ? nearest_sphere(prm, lights, o, d, &hit)
                                    : (lfloat)(NO_LIMIT);
        spec T = shadow_transmittance(prm, med, o, d, t_hit, 1, rng_s, counters, fresh);
        if (prm->area_lights > 0)
            path->L = sel3(path->L, mul3(escape_light(prm, lights, env, d, (lfloat)(0.0f),
                                                      (lint)(0)),
                                         spec_rgb(T)),
                           fresh);
        else if (prm->has_env && !prm->transparent)
            path->L = sel3(path->L,
                           FEATURE_ENV_MAP && prm->env_map ? mul3(env_light(prm, env, d),
                                                                  spec_rgb(T))
                                                           : rgb_times(vec3(prm->env), T),
                           fresh);
        path->alpha = select(path->alpha, coverage(spec_rgb(T)), fresh);
        for (int i = 0; prm->spheres && i < prm->n_lights; ++i) { /* an opaque sphere light */
            lmask at = fresh & (hit == i);
            path->L = sel3(path->L, rgb_times(vec3g(lights[i].color), T), at);
            path->alpha = select(path->alpha, (lfloat)(1.0f), at);
        }
        path->state = select(path->state, (lint)(PATH_DONE), fresh);
        return;
    }
    lvec3 beta = v3s(1.0f);
    lint hero = (lint)(-1);
    if (FEATURE_CHROMATIC ? m->spectral == SPECTRAL_CHANNEL || m->spectral == SPECTRAL_HERO
                          : 0) {
        /* A channel per path: alone ("channel") or as the hero of spectral MIS ("hero"). */
        lint c = min(to_lint_rtz(path_u1(prm, pix, s, (lint)(SAMPLER_PAIR_CHANNEL), 0, (luint)(0u), 1u,
                                         rng, fresh) *
                                 3.0f),
                     2);
        if (m->spectral == SPECTRAL_HERO)
            hero = c;
        else
            beta = v3(select((lfloat)(0.0f), (lfloat)(3.0f), c == 0),
                      select((lfloat)(0.0f), (lfloat)(3.0f), c == 1),
                      select((lfloat)(0.0f), (lfloat)(3.0f), c == 2));
    }
    path->beta = sel3(path->beta, beta, fresh);
    path->hero = select(path->hero, hero, fresh);
    path->R = sel3(path->R, v3s(1.0f), fresh); /* hero MIS: decision probabilities over the hero's */
    path->depth = select(path->depth, (lint)(0), fresh);
    path->medium = select(path->medium, (lint)(0), fresh);
    path->pdf_phase = select(path->pdf_phase, (lfloat)(0.0f), fresh);
    path->state = select(path->state, (lint)(PATH_START), fresh);
}

/* The throughput contributions are weighed by (hero MIS: the balance heuristic). */
static inline lvec3 weighted_beta(const Path *path) {
    return FEATURE_CHROMATIC ? sel3(path->beta, mul3(path->beta, mis_weights(path->R)),
                                    path->hero >= 0)
                             : path->beta;
}

/* The lanes of m begin a free flight along their ray: into the box, and (before the flight)
 * equiangular sampling of the point lights and the sampler's first uniform. A ray that
 * misses the medium ends its flight at once (an escape, with no walk). */
static inline STAGE void flight_begin(const Params *prm, global const Light *lights,
                                const MediumData *med, Path *path, Walk *wk, Rng *rng,
                                Rng *rng_s, lulong *counters, lmask m) {
    lfloat t0, t1, shift;
    lint hit = (lint)(-1);
    lfloat t_hit = (lfloat)(NO_LIMIT);
    if (prm->spheres) { /* the sphere light the ray meets first, from the vertex */
        t_hit = nearest_sphere(prm, lights, path->o, path->d, &hit);
        lfloat pdf_hit = (lfloat)(0.0f);
        for (int i = 0; i < prm->n_lights; ++i) {
            lmask at = m & (hit == i);
            if (ANY(at))
                pdf_hit = select(pdf_hit, sphere_light_pdf(&lights[i], path->o, path->d, t_hit),
                                 at);
        }
        path->pdf_hit = select(path->pdf_hit, pdf_hit, m);
        path->hit = select(path->hit, hit, m);
    }
    lint near;
    lvec3 o = enter_media_near(med, path->o, path->d, &t0, &t1, &shift, &near);
    if (prm->spheres) t1 = fmin(t1, t_hit - shift);
    path->o = sel3(path->o, o, m);
    path->t0 = select(path->t0, t0, m);
    path->t1 = select(path->t1, t1, m);
    path->state = select(path->state, (lint)(PATH_FLIGHT), m);
    lmask inside = m & (t1 > t0);
    /* No medium on the ray: the walk's outcome is an escape at t1, without a walk. */
    lmask outside = m & !inside;
    wk->event = select(wk->event, (lint)(EVENT_ESCAPE), outside);
    wk->t_end = select(wk->t_end, t1, outside);
    if (FEATURE_CHROMATIC ? med->m[0].spectral == SPECTRAL_CHANNEL : 0)
        /* A camera ray that meets no medium sees the same light in every channel: its path
         * carries all three, not 3x one (integrator.py) */
        path->beta = sel3(path->beta, v3s(1.0f), outside & (path->depth == 0));
    if (!ANY(inside)) return;
    lvec3 d = path->d;
    record_segment(med, o, d, t0, t1, RECORD_CAMERA, inside & (path->depth == 0));
    const int ea = equiangular_mode(prm, med);
    if (ea != EQUIANGULAR_OFF) {
        lmask eq = inside & (lanes_if(prm->max_depth < 0) | (path->depth < prm->max_depth));
        if (ANY(eq))
            path->L = sel3(path->L,
                           add3(path->L, mul3(weighted_beta(path),
                                              sample_equiangular_lights(
                                                  prm, lights, med, ea, o, d, t0, t1, path->pix,
                                                  path->s, path->depth, rng, rng_s, counters,
                                                  eq))),
                           eq);
    }
    lint pair = bounce_pair(path->depth, SAMPLER_FLIGHT);
    lmask preset = inside & (pair >= 0);
    if (prm->sampler != SAMPLER_INDEPENDENT && ANY(preset))
        rng_preset(rng, path_pair_u24(prm, path->pix, path->s, select((lint)(0), pair, preset),
                                      (luint)(0u), 1u).x,
                   preset);
    lmask heroic = FEATURE_CHROMATIC ? path->hero >= 0 : (lmask)(0);
    EmisMis emis = emis_plain();
    if (FEATURE_EMISSION && prm->emission_sampling != EMISSION_SAMPLING_COLLISION) {
        /* A flight from a scattering vertex: its emission is weighed against emission
         * sampling there (none with "light"); a camera ray's is not. */
        lfloat pdf = prm->emission_sampling == EMISSION_SAMPLING_MIS ? path->pdf_phase
                                                                     : (lfloat)(0.0f);
        emis.pdf = select((lfloat)(-1.0f), pdf, path->depth > 0);
        emis.shift = shift;
        emis.n = (float)prm->light_samples;
        emis.heuristic = prm->mis;
    }
    walk_begin(wk, med, o, d, t0, t1, near, (lint)(TRACK_FREE_FLIGHT),
               lanes_if(prm->decomposition), sel3(path->beta, path->R, heroic), path->hero, emis,
               inside);
}

/* The lanes of m have ended their free flight: its weight and emission, then escape,
 * scattering or the end of the path (trace_path after free_flight). Scattering leads to
 * next-event estimation. */
static inline STAGE void flight_end(const Params *prm, global const Light *lights,
                                    global const float *env,
                                    const MediumData *med, Path *path,
                              const Walk *wk, Rng *rng, lulong *counters, lmask m) {
    lmask walked = m & (path->t1 > path->t0);
    lint event = wk->event;
    path->t = select(path->t, wk->t_end, m);
#if FEATURE_CHROMATIC
    lmask heroic = walked & (path->hero >= 0), plain = walked & (path->hero < 0);
    if (FEATURE_EMISSION) path->L = sel3(path->L, add3(path->L, mul3(path->beta, wk->E)), heroic);
    path->R = sel3(path->R, mul3(path->R, spec_rgb(wk->T)), heroic);
    lfloat r = max3(path->R);
    path->R = sel3(path->R, scale3(path->R, 1.0f / r), heroic & (r > 0.0f)); /* ratios only */
    /* Channels no longer carried stay 0 (integrator.py). */
    if (FEATURE_EMISSION)
        path->L = sel3(path->L, add3(path->L, mul3(path->beta, keep_carried(path->beta, wk->E))),
                       plain);
    path->beta = sel3(path->beta, mul3(path->beta, keep_carried(path->beta, spec_rgb(wk->T))),
                      plain);
#else
    if (FEATURE_EMISSION) path->L = sel3(path->L, add3(path->L, mul3(path->beta, wk->E)), walked);
#endif
    rng_drop_preset(rng, walked);
    lvec3 beta_w = weighted_beta(path);
    lmask escaped = m & (event == EVENT_ESCAPE);
    lmask first = m & (path->depth == 0);
    if (prm->spheres) { /* a sphere light ends the ray: escaped are the rays to the sky */
        for (int i = 0; i < prm->n_lights; ++i) {
            lmask at = escaped & (path->hit == i);
            if (!ANY(at)) continue;
            lfloat w = select((lfloat)(1.0f),
                              mis_weight(prm->mis, path->pdf_phase,
                                         (float)prm->light_samples * path->pdf_hit),
                              path->depth > 0);
            path->L = sel3(path->L, add3(path->L, mul3(beta_w, scale3(v3u(vec3g(
                                                                     lights[i].color)), w))),
                           at);
        }
        escaped = escaped & (path->hit < 0);
    }
    path->alpha = select(path->alpha, select((lfloat)(1.0f), coverage(beta_w), escaped), first);
    if ((prm->has_env || prm->area_lights > 0) && ANY(escaped))
        path->L = sel3(path->L, add3(path->L, mul3(beta_w, escape_light(prm, lights, env,
                                                                        path->d,
                                                                        path->pdf_phase,
                                                                        path->depth))),
                       escaped);
    /* Scattering: the path goes on, unless its depth or throughput ends it. */
    lmask go = m & (event == EVENT_SCATTER);
    path->depth = path->depth + (go & 1);
    go = go & (lanes_if(prm->max_depth < 0) | (path->depth <= prm->max_depth));
    counters[C_SCATTER] += lane_ones(go);
    if (MEDIA_COUNT > 1 && ANY(go))
        path->medium = select(path->medium,
                              medium_pick(med, madd3(path->o, path->d, path->t), rng, counters,
                                          go),
                              go);
    lvec3 albedo = medium_albedo(med, path->medium);
#if FEATURE_ALBEDO_AOV
    path->aov = sel3(path->aov, albedo, go & (path->depth == 1));
#endif
    path->beta = sel3(path->beta, mul3(path->beta, albedo), go);
    beta_w = mul3(beta_w, albedo);
    go = go & (max3(beta_w) > 0.0f);
    path->beta_w = sel3(path->beta_w, beta_w, go);
    path->light = select(path->light, (lint)(0), go);
    path->sample = select(path->sample, (lint)(0), go);
    path->state = select(path->state, select((lint)(PATH_DONE), (lint)(PATH_NEE), go), m);
}

#if FEATURE_EMISSION
/* One emission-sampling shadow ray per lane of `active` from vertex p (the path arrived
 * along d and scatters in medium k): the ray of sample_emitters in integrator.py, without
 * its transmittance. Writes the direction, the distance and the contribution per unit
 * throughput (f sigma_a Le w_L / (N pdf dist^2), RGB); returns the lanes with a ray (the
 * others' sample carries nothing: no density, the vertex itself, or no emission there). */
static inline lmask emitter_ray(const Params *prm, const MediumData *med, lvec3 p, lvec3 d,
                                lint k, Rng *rng, lulong *counters, lvec3 *w, lfloat *dist,
                                lvec3 *contrib, lmask active) {
    lfloat u0 = rng_next(rng, active);
    lfloat u1 = rng_next(rng, active);
    lfloat u2 = rng_next(rng, active);
    lfloat u3 = rng_next(rng, active);
    lfloat u4 = rng_next(rng, active);
    lfloat pdf;
    lvec3 y = sample_emitter(med, u0, u1, u2, u3, u4, &pdf, active);
    lmask ok = active & (pdf > 0.0f);
    *w = direction_to(p, y, dist);
    ok = ok & (*dist > 0.0f);
#if MEDIA_COUNT == 1
    lfloat mu = extinction(med, y, (lfloat)(NO_LIMIT), counters, ok);
#else
    lfloat mu = (lfloat)(0.0f);
#endif
    lvec3 src = emission_term(med, media_at(med, y, ok), y, mu, (lfloat)(1.0f), v3s(1.0f),
                              counters, ok);
    ok = ok & (max3(src) > 0.0f);
    lfloat f = medium_phase_eval(med, k, d, *w);
    /* f w / (n pdf dist^2), the densities in 1/sr times dist^2 (integrator.py) */
    lfloat q = (float)prm->light_samples * pdf * *dist * *dist;
    lfloat g = prm->emission_sampling == EMISSION_SAMPLING_MIS
                   ? f * mis_weight_over(prm->mis, q, f * majorant_at(med, y, ok))
                   : f / q;
    *contrib = sel3(*contrib, scale3(src, g), ok);
    return ok;
}
#endif

/* Adds a shadow ray's contribution (its transmittance times contrib) and moves to the next
 * sample of the light. */
static inline void shadow_add(Path *path, spec T, lmask m) {
    path->L = sel3(path->L, add3(path->L, mul3(path->contrib, spec_rgb(T))), m);
    path->sample = path->sample + (m & 1);
}

/* The lanes of m choose their next shadow ray (sample_direct in integrator.py, one ray at a
 * time: every light's light_samples rays in light order, then the environment's) and begin
 * its walk; a lane whose rays are all done goes on to roulette. A ray that meets no medium
 * has T = 1 at once; with a per-segment shadow estimator the transmittance is estimated here
 * and the lane chooses again. */
static inline STAGE void nee_next(const Params *prm, global const Light *lights,
                                  global const float *env, const MediumData *med,
                            Path *path, Walk *wk, Rng *rng, Rng *rng_s, lulong *counters,
                            lmask m) {
    const Medium *md = &med->m[0];
    const int ea = equiangular_mode(prm, med);
    const int n = prm->light_samples;
    const float inv_n = 1.0f / (float)n;
    lvec3 p = madd3(path->o, path->d, path->t);
    /* Emission sampling's slot after the sky's (the lights' order of sample_direct). */
    const int glow_slot = FEATURE_EMISSION &&
                          prm->emission_sampling != EMISSION_SAMPLING_COLLISION;
    lmask choosing = m;
    while (ANY(choosing)) {
        /* The ray each choosing lane takes now (if it has one). */
        lmask ray = (lmask)(0), dark = (lmask)(0); /* dark: a sample without a ray */
        lint target = (lint)(-1);                    /* the sphere the ray is for */
        lvec3 wl = v3s(0.0f);
        lfloat dist = (lfloat)(NO_LIMIT);
        for (int i = 0; i < prm->n_lights; ++i) {
            lmask at = choosing & (path->light == i);
            if (!ANY(at)) continue;
            global const Light *lt = &lights[i];
            lfloat di, f;
            lvec3 w;
            lmask take;
            if (is_area_light(lt)) { /* a sampled direction per shadow ray */
                take = at & (path->sample < n);
                uint count;
                luint j = light_point(prm, i, as_luint(path->sample), &count);
                lvec2 u = path_u2(prm, path->pix, path->s,
                                  bounce_pair(path->depth - 1, SAMPLER_LIGHT), j, count, rng,
                                  take);
                lfloat pdf_l, le;
                w = sample_area_light(lt, p, u.x, u.y, &di, &pdf_l, &le);
                lfloat fp = medium_phase_eval(med, path->medium, path->d, w);
                f = fp * le * mis_weight(prm->mis, (float)n * pdf_l, fp) * inv_n / pdf_l;
                dark = dark | (take & !(pdf_l > 0.0f));
                target = select(target, (lint)(i), take);
            } else {
                lfloat falloff;
                w = light_ray(prm, md, ea, lt, path->o, path->d, path->t0, path->t1, path->t,
                              &di, &falloff);
                take = at & (falloff > 0.0f) & (path->sample < n);
                f = medium_phase_eval(med, path->medium, path->d, w) * falloff * inv_n;
            }
            /* An unlit light, or one whose rays are all done: the next light. */
            path->light = path->light + ((at & !take) & 1);
            path->sample = select(path->sample, (lint)(0), at & !take);
            path->contrib = sel3(path->contrib,
                                 mul3(path->beta_w, scale3(v3u(vec3g(lt->color)), f)), take);
            wl = sel3(wl, w, take);
            dist = select(dist, di, take);
            ray = ray | take;
        }
        lmask sky = choosing & !ray & (path->light == prm->n_lights);
        if (prm->has_env && ANY(sky)) {
            lmask take = sky & (path->sample < n);
            uint count;
            luint j = light_point(prm, prm->n_lights, as_luint(path->sample), &count);
            lvec2 u = path_u2(prm, path->pix, path->s, bounce_pair(path->depth - 1, SAMPLER_LIGHT),
                              j, count, rng, take);
            lfloat pdf_l;
            lvec3 w = sample_env_light(prm, env, u.x, u.y, &pdf_l, take);
            lfloat f = medium_phase_eval(med, path->medium, path->d, w);
            lfloat mw = mis_weight(prm->mis, (float)n * pdf_l, f) * inv_n;
            /* (pdf 0: a pole of the map, a set of measure zero; the ray carries nothing) */
            lfloat g = select((lfloat)(0.0f), f * mw / pdf_l, pdf_l > 0.0f);
            path->contrib = sel3(path->contrib, mul3(path->beta_w,
                                                     scale3(env_light(prm, env, w), g)),
                                 take);
            wl = sel3(wl, w, take);
            dist = select(dist, (lfloat)(NO_LIMIT), take);
            ray = ray | take;
        }
#if FEATURE_EMISSION
        if (glow_slot) { /* the sky's slot done (or none): the emitters', n_lights + 1 */
            lmask sky_done = sky & (lanes_if(!prm->has_env) | (path->sample >= n));
            path->light = path->light + (sky_done & 1);
            path->sample = select(path->sample, (lint)(0), sky_done);
        }
        lmask glow = choosing & !ray & (path->light == prm->n_lights + 1);
        if (glow_slot && ANY(glow)) {
            lmask take = glow & (path->sample < n);
            lvec3 w;
            lfloat di;
            lmask lit = emitter_ray(prm, med, p, path->d, path->medium, rng, counters, &w, &di,
                                    &path->contrib, take);
            path->contrib = sel3(path->contrib, mul3(path->beta_w, path->contrib), take);
            dark = dark | (take & !lit);
            wl = sel3(wl, w, take);
            dist = select(dist, di, take);
            ray = ray | take;
        }
#endif
        /* A sample without a direction, or whose ray a sphere light blocks: no ray, and no
         * transmittance estimated (sample_direct's `continue`). */
        lmask blocked = ray & (dark | occluded(prm, lights, p, wl, dist, target));
        path->sample = path->sample + (blocked & 1);
        ray = ray & !blocked;
        /* Lanes past the last light: next-event estimation is over. */
        lmask over = glow_slot ? choosing & !ray &
                                     ((path->light > prm->n_lights + 1) |
                                      ((path->light == prm->n_lights + 1) & (path->sample >= n)))
                               : choosing & !ray &
                                     ((path->light >= prm->n_lights + (prm->has_env ? 1 : 0)) |
                                      (sky & (path->sample >= n)));
        path->state = select(path->state, (lint)(PATH_BOUNCE), over);
        choosing = choosing & !over;
        if (!ANY(ray)) continue;
        /* shadow_transmittance's clip, then the walk (or the estimate) of each ray. */
        lfloat t0, t1, shift;
        lint near;
        lvec3 o = enter_media_near(med, p, wl, &t0, &t1, &shift, &near);
        t1 = fmin(t1, dist - shift);
        lmask go = ray & (t1 > t0);
        shadow_add(path, spec_s((lfloat)(1.0f)), ray & !go);
        if (!ANY(go)) continue;
        record_segment(med, o, wl, t0, t1, RECORD_SHADOW, go);
        counters[C_SHADOW] += lane_ones(go);
#ifdef SHADOW_TECHNIQUE
        rng_swap(rng, rng_s, go); /* the walk loop draws from `rng` */
        walk_begin(wk, med, o, wl, t0, t1, near, (lint)(SHADOW_TECHNIQUE),
                   lanes_if(SHADOW_CONTROL), v3s(1.0f), (lint)(-1), emis_plain(), go);
        path->state = select(path->state, (lint)(PATH_SHADOW), go);
        choosing = choosing & !go;
#else
        shadow_add(path, SHADOW_ESTIMATOR(med, o, wl, t0, t1, rng_s, counters, prm->max_steps, go),
                   go);
#endif
    }
}

/* The lanes of m have ended a shadow ray's walk. */
static inline STAGE void shadow_end(Path *path, const Walk *wk, Rng *rng, Rng *rng_s, lmask m) {
    rng_swap(rng, rng_s, m);
    shadow_add(path, wk->T, m);
    path->state = select(path->state, (lint)(PATH_NEE), m);
}

/* Russian roulette and a phase-sampled direction for the lanes of m (trace_path after
 * sample_direct): a new flight, or the end of the path. */
static inline STAGE void path_bounce(const Params *prm, const MediumData *med, Path *path,
                                     Rng *rng, lmask m) {
    lvec3 p = madd3(path->o, path->d, path->t);
    lmask alive = m;
    lmask roulette = m & (path->depth >= prm->rr_depth);
    if (ANY(roulette)) {
        lfloat q = survival_probability(prm, path->beta_w, medium_albedo(med, path->medium));
        lfloat u = path_u1(prm, path->pix, path->s, bounce_pair(path->depth - 1, SAMPLER_FLIGHT),
                           1, (luint)(0u), 1u, rng, roulette);
        lmask end = roulette & (u >= q);
        alive = alive & !end;
        path->beta = sel3(path->beta, div3(path->beta, q), roulette & !end);
    }
    lvec2 up = path_u2(prm, path->pix, path->s, bounce_pair(path->depth - 1, SAMPLER_PHASE),
                       (luint)(0u), 1u, rng, alive);
    lfloat pdf;
    lvec3 d = medium_phase_sample(med, path->medium, up.x, up.y, path->d, &pdf);
    path->d = sel3(path->d, d, alive);
    path->pdf_phase = select(path->pdf_phase, pdf, alive);
    path->o = sel3(path->o, p, alive);
    path->state = select(path->state, select((lint)(PATH_DONE), (lint)(PATH_START), alive), m);
}

/* The samples of the lanes of m (RGBA; with FEATURE_ALBEDO_AOV, RGBA and the albedo AOV
 * padded to 8 floats), filtered (guard "sample filter", guards.h: a dropped sample is 0 in
 * every channel), to out[job]. */
static inline STAGE void path_write(const Params *prm, const Path *path, global float *out,
                              lulong *counters, lmask m) {
    lmask ok = sample_ok(path->L, prm->signed_samples);
    counters[C_DROPPED] += lane_ones(m & !ok);
    lvec3 c = sel3(v3s(0.0f), path->L, ok);
    lfloat a = select((lfloat)(0.0f), path->alpha, ok);
#if FEATURE_ALBEDO_AOV
    lvec3 aov = sel3(v3s(0.0f), path->aov, ok);
#endif
    for (int l = 0; l < LANES; ++l)
        if (lane_on(m, l))
#if FEATURE_ALBEDO_AOV
            vstore8((float8)(lane_vec3(c, l), lane_float(a, l), lane_vec3(aov, l), 0.0f),
                    lane_uint(path->job, l), out);
#else
            vstore4((float4)(lane_vec3(c, l), lane_float(a, l)), lane_uint(path->job, l), out);
#endif
}

/* Work-item i renders the jobs [b J, (b + 1) J) of the launch (J = launch.jobs_per_item):
 * block b is dealt to it in runs of launch.item_group blocks with launch.item_stride (the
 * host's item_deal in volmc/backends/opencl.py says how and why). Job j is sample
 * launch.sample_start + j % n_samples of pixel launch.pix_start + j / n_samples (row-major
 * pixel indices: a band of rows, or every pixel), and writes its value to out[j] (RGBA). A
 * lane whose path ends takes the work-item's next job. A pixel's samples depend on its index
 * and the sample's alone, so any split into bands, launches, work-items or lanes gives the
 * same values. A NaN, infinite or negative sample is written as 0 and counted as dropped,
 * exactly as in the reference. Counters: one row per work-item. */
kernel void render_batch(const Params prm, global const Medium *media, const Launch launch,
                         global const Light *lights, global const float *env,
                         global const float *grid,
                         global const float *maj, global const float *mnr,
                         global const float *emis, global const float *table,
                         global const int *bricks, global const float *pool,
                         global const int *nodes, global float *rec, global float *out,
                         global ulong *counters_out) {
    uint item = get_global_id(0);
    uint n_jobs = launch.n_pix * launch.n_samples;
    uint n_items = (n_jobs + launch.jobs_per_item - 1) / launch.jobs_per_item;
    if (item >= n_items) return;
    uint runs = n_items / launch.item_group, run = item / launch.item_group;
    uint block = run < runs
        ? (uint)((ulong)run * launch.item_stride % runs) * launch.item_group
          + item % launch.item_group
        : item;
    uint next = block * launch.jobs_per_item;
    uint last = min(next + launch.jobs_per_item, n_jobs);
    /* Each pixel's record is [K + 1][RECORD_COLUMNS] (K = rec_capacity); without recording,
     * rec is a 1-float dummy that nothing may index. */
    MediumData med;
    for (int i = 0; i < MEDIA_COUNT; ++i) med.m[i] = media[i];
    med.grid = grid;
    med.maj = maj;
    med.mnr = mnr;
    med.emis = emis;
    med.table = table;
    med.bricks = bricks;
    med.pool = pool;
    med.nodes = nodes;
    med.rec = FEATURE_RECORD && launch.rec_capacity > 0 ? rec : 0;
    med.rec_capacity = launch.rec_capacity;
    med.rec_pixel = (lint)(-1);
    ulong seed = ((ulong)prm.seed_hi << 32) | (ulong)prm.seed_lo;
    lulong cnt[N_COUNTERS];
    for (int k = 0; k < N_COUNTERS; ++k) cnt[k] = (lulong)(0);
    Rng rng = rng_empty(), rng_s = rng_empty();
    Walk wk = {0};   /* records start defined in every lane (lanes.h) */
    Path path = {0};
    path.state = (lint)(PATH_IDLE);
    while (true) {
        /* Path logic until every lane walks or has nothing left. */
        while (true) {
            lmask waiting = !wk.live;
            lmask m = waiting & (path.state == PATH_FLIGHT);
            if (ANY(m)) flight_end(&prm, lights, env, &med, &path, &wk, &rng, cnt, m);
            m = waiting & (path.state == PATH_SHADOW);
            if (ANY(m)) shadow_end(&path, &wk, &rng, &rng_s, m);
            m = path.state == PATH_NEE;
            if (ANY(m)) nee_next(&prm, lights, env, &med, &path, &wk, &rng, &rng_s, cnt, m);
            m = path.state == PATH_BOUNCE;
            if (ANY(m)) path_bounce(&prm, &med, &path, &rng, m);
            m = path.state == PATH_DONE;
            if (ANY(m)) {
                path_write(&prm, &path, out, cnt, m);
                path.state = select(path.state, (lint)(PATH_IDLE), m);
            }
            /* Idle lanes take the next jobs, in lane order. */
            lmask idle = path.state == PATH_IDLE;
            if (next < last && ANY(idle)) {
                LaneUints job;
                job.v = (luint)(0);
                lmask fresh = (lmask)(0);
                for (int l = 0; l < LANES && next < last; ++l) {
                    if (!lane_on(idle, l)) continue;
                    job.a[l] = next++;
                    fresh = fresh | (LANE_IOTA == l);
                }
                luint j = job.v;
                path_start(&prm, lights, env, &med, &path, seed, j,
                           launch.pix_start + j / launch.n_samples,
                           launch.sample_start + j % launch.n_samples, &rng, &rng_s, cnt,
                           fresh);
            }
            m = path.state == PATH_START;
            if (ANY(m)) flight_begin(&prm, lights, &med, &path, &wk, &rng, &rng_s, cnt, m);
            lmask stuck = !wk.live & (path.state != PATH_IDLE);
            if (!ANY(stuck) && (next >= last || !ANY(path.state == PATH_IDLE))) break;
        }
        if (!ANY(wk.live)) break;
        /* Walk until three quarters of the lanes wait for the path logic (or no walk is
         * left): the logic then serves more lanes per pass, and the walks lose less
         * occupancy than the logic gains. On a Zen 5 (AVX-512) half was about 10 % faster
         * than a pass whenever one lane waits, at W = 4, 8 and 16 alike, and three quarters
         * measured the same as half; on a Zen 3 (AVX2) three quarters takes 0.93x half's CPU
         * time on the default cloud at W = 8 (0.93x and 0.96x on two fbm clouds; 0.96x at
         * W = 4 and 16), with the same image. */
#ifndef LOGIC_LANES
#define LOGIC_LANES ((3 * LANES + 3) / 4)
#endif
        lmask waiting = !wk.live & (path.state != PATH_IDLE);
        do {
            waiting = waiting | walk_step(&wk, &med, WALK_TECHNIQUES, &rng, cnt, prm.max_steps);
        } while (ANY(wk.live) && lane_count(waiting) < LOGIC_LANES);
    }
    for (int k = 0; k < N_COUNTERS; ++k)
        counters_out[(size_t)item * N_COUNTERS + k] = lane_sum_ulong(cnt[k]);
}
