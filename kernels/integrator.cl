/* Volumetric path tracer kernel. Twin of volmc/reference/integrator.py: the algorithm, the order
 * of random numbers and the Russian-roulette policy are described there.
 *
 * Built for the scene: -DFEATURE_X=0/1 options (volmc/scene/features.py; features.h defaults
 * every one to 1) turn a code path off where the scene cannot take it; each is a plain constant
 * in an ordinary `if`, so the compiler drops the dead path. Only the switches `volmc bench
 * specialise` shows to pay are kept (README, "Specialisation"); a build with every one on
 * renders any scene. SHADOW_ESTIMATOR names the shadow-ray estimator (render.transmittance);
 * VIEW_ESTIMATOR, defined only where it differs ("auto"), the one for camera rays that cannot
 * scatter, whose transmittance is the sample.
 * params.h (generated from volmc/params.py and volmc/constants.py) defines the records and
 * constants. */

#include "params.h"
#include "features.h"
#include "guards.h"
#include "rng.h"
#include "sampler.h"
#include "sampling.h"
#include "phase.h"
#include "medium.h"
#include "free_flight.h"
#include "estimators.h"

static inline float3 vec3g(global const float v[3]) { return (float3)(v[0], v[1], v[2]); }

/* Returns t_enter, writes t_exit; no hit when t_enter >= t_exit. Zero direction components
 * (including -0.0) are handled without 0 * inf. */
static inline float ray_box(float3 o, float3 d, float3 bmin, float3 bmax, float *t_exit) {
    float t0 = -FLT_MAX, t1 = FLT_MAX;  /* "no limit": see NO_LIMIT in guards.h */
    float oa[3] = {o.x, o.y, o.z}, da[3] = {d.x, d.y, d.z};
    float lo[3] = {bmin.x, bmin.y, bmin.z}, hi[3] = {bmax.x, bmax.y, bmax.z};
    for (int a = 0; a < 3; ++a) {
        if (da[a] == 0.0f) {
            if (oa[a] < lo[a] || oa[a] > hi[a]) {
                *t_exit = -FLT_MAX;
                return FLT_MAX;
            }
        } else {
            float inv = 1.0f / da[a];
            float ta = (lo[a] - oa[a]) * inv;
            float tb = (hi[a] - oa[a]) * inv;
            t0 = fmax(t0, fmin(ta, tb));
            t1 = fmin(t1, fmax(ta, tb));
        }
    }
    *t_exit = t1;
    return t0;
}

/* Guard "entry re-basing" (robustness case 10, 11, 13): clips ray o + t d to the box and, when the
 * box is entered from outside (t_enter > 0), moves the origin to the entry point, snapped onto
 * the box (clamped into it, and exactly onto the entry face), and clips again from there.
 * Every later distance is then local to the box: no tracking loop accumulates a large t (a
 * far camera), the chord comes from nearby numbers (exact for a thin slab seen from afar),
 * and a dense medium is entered exactly at its face, never a rounding error inside it (which
 * would bury the path). Returns the origin to use; writes the local segment [*t0, *t1] (no
 * medium when *t1 <= *t0) and the distance *shift the origin moved along d. Twin of
 * enter_box in integrator.py. */
static inline float3 enter_box(float3 o, float3 d, float3 bmin, float3 bmax, float *t0, float *t1,
                               float *shift) {
    float te = ray_box(o, d, bmin, bmax, t1);
    *shift = 0.0f;
    if (!(te > 0.0f && *t1 > te)) {
        *t0 = fmax(te, 0.0f);
        return o;
    }
    float oa[3] = {o.x, o.y, o.z}, da[3] = {d.x, d.y, d.z};
    float lo[3] = {bmin.x, bmin.y, bmin.z}, hi[3] = {bmax.x, bmax.y, bmax.z};
    float pa[3];
    int entry = 0;
    float best = -FLT_MAX;
    for (int a = 0; a < 3; ++a) {
        pa[a] = clamp(oa[a] + te * da[a], lo[a], hi[a]);
        if (da[a] != 0.0f) {
            float tin = ((da[a] > 0.0f ? lo[a] : hi[a]) - oa[a]) / da[a];
            if (tin > best) {
                best = tin;
                entry = a;
            }
        }
    }
    pa[entry] = da[entry] > 0.0f ? lo[entry] : hi[entry];
    float3 p = (float3)(pa[0], pa[1], pa[2]);
    *shift = te;
    ray_box(p, d, bmin, bmax, t1);
    *t0 = 0.0f;
    return p;
}

/* x with the components where beta is 0 set to 0 (twin in integrator.py). */
static inline float3 keep_carried(float3 beta, float3 x) {
    return (float3)(beta.x != 0.0f ? x.x : 0.0f, beta.y != 0.0f ? x.y : 0.0f,
                    beta.z != 0.0f ? x.z : 0.0f);
}

static inline float3 camera_ray(const Params *prm, int px, int py, float u1, float u2,
                                float3 *dir) {
    float sx = (2.0f * ((float)px + u1) / (float)prm->width - 1.0f) * prm->half_height * prm->aspect;
    float sy = (1.0f - 2.0f * ((float)py + u2) / (float)prm->height) * prm->half_height;
    float3 f = vec3(prm->forward), r = vec3(prm->right), u = vec3(prm->up), e = vec3(prm->eye);
    if (prm->cam_type == CAMERA_ORTHOGRAPHIC) {
        *dir = f;
        return e + sx * r + sy * u;
    }
    *dir = normalize(f + sx * r + sy * u);
    return e;
}

static inline spec shadow_transmittance(const Params *prm, const MediumData *med, float3 o,
                                        float3 d, float t_max, int view, Rng *rng_s,
                                        ulong *counters) {
    float t0, t1, shift;
    o = enter_box(o, d, vec3(med->m.bmin), vec3(med->m.bmax), &t0, &t1, &shift);
    t1 = fmin(t1, t_max - shift);
    if (t1 <= t0) return 1.0f;
    record_segment(med, o, d, t0, t1, RECORD_SHADOW);
    counters[C_SHADOW] += 1;
#ifdef VIEW_ESTIMATOR
    if (view) return VIEW_ESTIMATOR(med, o, d, t0, t1, rng_s, counters, prm->max_steps);
#endif
    return SHADOW_ESTIMATOR(med, o, d, t0, t1, rng_s, counters, prm->max_steps);
}

/* Where a path's uniforms come from (render.sampler): twins of bounce_pair, path_pair_u24,
 * path_u2 and path_u1 in integrator.py, which describe them. */
static inline int bounce_pair(int b, int offset) {
    return b >= SAMPLER_BOUNCES ? -1 : SAMPLER_FIRST_BOUNCE + b * SAMPLER_PAIRS_PER_BOUNCE + offset;
}

static inline uint2 path_pair_u24(const Params *prm, uint pix, uint s, int pair, uint j,
                                  uint count) {
    return sampler_pair(prm->sampler, prm->seed_lo, prm->seed_hi, pix, s * count + j,
                        (uint)pair, prm->spp * count);
}

static inline float2 path_u2(const Params *prm, uint pix, uint s, int pair, uint j, uint count,
                             Rng *rng) {
    if (prm->sampler == SAMPLER_INDEPENDENT || pair < 0) {
        float u1 = rng_next(rng);
        return (float2)(u1, rng_next(rng));
    }
    return convert_float2(path_pair_u24(prm, pix, s, pair, j, count)) * UNIFORM_SCALE;
}

static inline float path_u1(const Params *prm, uint pix, uint s, int pair, int axis, uint j,
                            uint count, Rng *rng) {
    if (prm->sampler == SAMPLER_INDEPENDENT || pair < 0) return rng_next(rng);
    uint2 a = path_pair_u24(prm, pix, s, pair, j, count);
    return (float)(axis == 1 ? a.y : a.x) * UNIFORM_SCALE;
}

/* How a path treats point lights (render.equiangular; twin constants in integrator.py):
 * next-event estimation only, equiangular sampling alone, or both combined by MIS. */
#define EQUIANGULAR_OFF 0
#define EQUIANGULAR_ALONE 1
#define EQUIANGULAR_MIS 2

static inline int equiangular_mode(const Params *prm, const Medium *m) {
    if (!prm->equiangular) return EQUIANGULAR_OFF;
    return m->density_kind == DENSITY_CONSTANT && m->spectral == SPECTRAL_GREY
               ? EQUIANGULAR_MIS
               : EQUIANGULAR_ALONE;
}

/* Returns the unit direction from p to c, writes the distance (0 when p = c). */
static inline float3 direction_to(float3 p, float3 c, float *dist) {
    float3 v = c - p;
    *dist = sqrt(dot(v, v));
    return *dist > 0.0f ? v / *dist : v;
}

/* Returns the ray parameter h of c's foot on the ray o + t d, writes c's distance D from the
 * ray's line. */
static inline float foot_on_ray(float3 c, float3 o, float3 d, float *D) {
    float3 v = c - o;
    float h = dot(v, d);
    float3 w = v - h * d;
    *D = sqrt(dot(w, w));
    return h;
}

/* sigma e^{-sigma (t - t0)}: free flight's collision density in a homogeneous grey medium. */
static inline float free_flight_pdf(const Medium *m, float t0, float t) {
    float s = m->scale * m->density;
    return s * exp(-s * (t - t0));
}

/* MIS weight of next-event estimation towards point light c (twin in integrator.py). */
static inline float point_light_nee_weight(const Params *prm, const Medium *m, int ea, float3 c,
                                           float3 o, float3 d, float t0, float t1, float t) {
    if (ea == EQUIANGULAR_OFF) return 1.0f;
    float D;
    float h = foot_on_ray(c, o, d, &D);
    if (!(D > 0.0f)) return 1.0f;
    if (ea == EQUIANGULAR_ALONE) return 0.0f;
    return mis_weight(prm->mis, free_flight_pdf(m, t0, t), equiangular_pdf(t, h, D, t0, t1));
}

/* Direct light at o + t d towards -d per unit throughput, with render.light_samples shadow
 * rays per light (twin of sample_direct in integrator.py). */
static inline float3 sample_direct(const Params *prm, global const Light *lights,
                                   const MediumData *med, int ea, float3 o, float3 d, float t0,
                                   float t1, float t, uint pix, uint s, int b, Rng *rng,
                                   Rng *rng_s, ulong *counters) {
    const Medium *m = &med->m;
    float3 p = o + t * d;
    int n = prm->light_samples;
    float inv_n = 1.0f / (float)n;
    float3 L = (float3)(0.0f);
    for (int i = 0; i < prm->n_lights; ++i) {
        float3 wl;
        float3 c = vec3g(lights[i].vec);
        float dist = NO_LIMIT, falloff = 1.0f;
        if (lights[i].type == LIGHT_DIRECTIONAL) {
            wl = -c;
        } else {
            wl = direction_to(p, c, &dist);
            if (!(dist > 0.0f)) continue;
            falloff = point_light_nee_weight(prm, m, ea, c, o, d, t0, t1, t) / (dist * dist);
            if (falloff <= 0.0f) continue;
        }
        float f = phase_eval(m->phase_kind, m->g, dot(d, wl)) * falloff * inv_n;
        for (int j = 0; j < n; ++j) {
            spec tr = shadow_transmittance(prm, med, p, wl, dist, 0, rng_s, counters);
            L += vec3g(lights[i].color) * (tr * f);
        }
    }
    if (prm->has_env) {
        int pair = bounce_pair(b, SAMPLER_LIGHT);
        for (int j = 0; j < n; ++j) {
            float2 u = path_u2(prm, pix, s, pair, (uint)j, (uint)n, rng);
            float pdf_l;
            float3 wl = sample_uniform_sphere(u.x, u.y, &pdf_l);
            float f = phase_eval(m->phase_kind, m->g, dot(d, wl));
            spec tr = shadow_transmittance(prm, med, p, wl, NO_LIMIT, 0, rng_s, counters);
            float w = mis_weight(prm->mis, (float)n * pdf_l, f) * inv_n;
            L += vec3(prm->env) * (tr * (f * w / pdf_l));
        }
    }
    return L;
}

/* Light from every point light scattered once inside [t0, t1] of the ray o + t d, by
 * equiangular sampling (twin of sample_equiangular_lights in integrator.py, which derives
 * it). */
static inline float3 sample_equiangular_lights(const Params *prm, global const Light *lights,
                                               const MediumData *med, int ea, float3 o, float3 d,
                                               float t0, float t1, uint pix, uint s, int b,
                                               Rng *rng, Rng *rng_s, ulong *counters) {
    const Medium *m = &med->m;
    float3 L = (float3)(0.0f);
    for (int i = 0; i < prm->n_lights; ++i) {
        if (lights[i].type != LIGHT_POINT) continue;
        float u = path_u1(prm, pix, s, bounce_pair(b, SAMPLER_EQUIANGULAR), 0, (uint)i,
                          (uint)prm->n_lights, rng);
        float3 c = vec3g(lights[i].vec);
        float D;
        float h = foot_on_ray(c, o, d, &D);
        if (!(D > 0.0f)) continue;
        float pdf;
        float t = sample_equiangular(u, h, D, t0, t1, &pdf);
        if (!(pdf > 0.0f)) continue;
        float3 p = o + t * d;
        float dist;
        float3 wl = direction_to(p, c, &dist);
        if (!(dist > 0.0f)) continue;
        spec sig = medium_chroma(med) * extinction(med, p, NO_LIMIT, counters);
        float3 sig_s = vec3(m->albedo) * sig;
        if (fmax(sig_s.x, fmax(sig_s.y, sig_s.z)) <= 0.0f) continue;
        counters[C_SHADOW] += 1;
        spec t_cam = SHADOW_ESTIMATOR(med, o, d, t0, t, rng_s, counters, prm->max_steps);
        spec t_lt = shadow_transmittance(prm, med, p, wl, dist, 0, rng_s, counters);
        float w = ea == EQUIANGULAR_MIS ? mis_weight(prm->mis, pdf, free_flight_pdf(m, t0, t))
                                        : 1.0f;
        float f = phase_eval(m->phase_kind, m->g, dot(d, wl)) * w / (dist * dist * pdf);
        L += vec3g(lights[i].color) * (sig_s * (t_cam * t_lt) * f);
    }
    return L;
}

/* Russian roulette's survival probability (render.rr; twin in integrator.py). */
static inline float survival_probability(const Params *prm, float3 beta_w, float3 albedo) {
    float3 x = prm->rr == RR_ALBEDO ? beta_w * albedo : beta_w;
    return fmin(fmax(x.x, fmax(x.y, x.z)), RR_MAX_SURVIVAL);
}

static inline float3 trace_path(const Params *prm, global const Light *lights,
                                const MediumData *med, int px, int py, uint s, Rng *rng,
                                Rng *rng_s, ulong *counters) {
    const Medium *m = &med->m;
    float3 bmin = vec3(m->bmin), bmax = vec3(m->bmax);
    float3 albedo = vec3(m->albedo);
    float3 env = vec3(prm->env);
    float3 L = (float3)(0.0f);
    float3 beta = (float3)(1.0f);
    uint pix = (uint)(py * prm->width + px);
    float2 uc = path_u2(prm, pix, s, SAMPLER_PAIR_PIXEL, 0u, 1u, rng);
    float3 d;
    float3 o = camera_ray(prm, px, py, uc.x, uc.y, &d);
    const int emissive = FEATURE_EMISSION ? m->emission_kind != EMISSION_NONE : 0;
    if (!emissive && (prm->max_depth == 0 || fmax(albedo.x, fmax(albedo.y, albedo.z)) <= 0.0f)) {
        /* No scattering can contribute: environment times transmittance (see integrator.py). */
        if (!prm->has_env) return L;
        return env * shadow_transmittance(prm, med, o, d, NO_LIMIT, 1, rng_s, counters);
    }
    int hero = -1;
    float3 R = (float3)(1.0f); /* hero MIS: decision probabilities over the hero's */
    if (FEATURE_CHROMATIC ? m->spectral == SPECTRAL_CHANNEL || m->spectral == SPECTRAL_HERO
                          : 0) {
        /* A channel per path: alone ("channel") or as the hero of spectral MIS ("hero"). */
        int c = min(convert_int_rtz(path_u1(prm, pix, s, SAMPLER_PAIR_CHANNEL, 0, 0u, 1u, rng) *
                                    3.0f),
                    2);
        if (m->spectral == SPECTRAL_HERO)
            hero = c;
        else
            beta = (float3)(c == 0 ? 3.0f : 0.0f, c == 1 ? 3.0f : 0.0f, c == 2 ? 3.0f : 0.0f);
    }
    int depth = 0;
    float pdf_phase = 0.0f;
    const int ea = equiangular_mode(prm, m);
    const float n_env = (float)prm->light_samples * uniform_sphere_pdf();
    while (true) {
        float t0, t1, shift;
        o = enter_box(o, d, bmin, bmax, &t0, &t1, &shift);
        int event = EVENT_ESCAPE;
        float t = t1;
        if (t1 > t0) {
            if (depth == 0) record_segment(med, o, d, t0, t1, RECORD_CAMERA);
            if (ea != EQUIANGULAR_OFF && (prm->max_depth < 0 || depth < prm->max_depth)) {
                float3 bw = FEATURE_CHROMATIC && hero >= 0 ? beta * mis_weights(R) : beta;
                L += bw * sample_equiangular_lights(prm, lights, med, ea, o, d, t0, t1, pix, s,
                                                    depth, rng, rng_s, counters);
            }
            int pair = bounce_pair(depth, SAMPLER_FLIGHT);
            if (prm->sampler != SAMPLER_INDEPENDENT && pair >= 0)
                rng_preset(rng, path_pair_u24(prm, pix, s, pair, 0u, 1u).x);
            spec w;
            float3 E;
            event = free_flight(med, o, d, t0, t1, prm->decomposition, hero >= 0 ? R : beta,
                                hero, rng, counters, prm->max_steps, &t, &w, &E);
#if FEATURE_CHROMATIC
            if (hero >= 0) {
                if (FEATURE_EMISSION) L += beta * E;
                R *= w;
                float r = fmax(R.x, fmax(R.y, R.z));
                if (r > 0.0f) R *= 1.0f / r; /* ratios only */
            } else {
                /* Channels no longer carried stay 0 (integrator.py). */
                if (FEATURE_EMISSION) L += beta * keep_carried(beta, E);
                beta *= keep_carried(beta, w);
            }
#else
            if (FEATURE_EMISSION) L += beta * E;
#endif
            rng_drop_preset(rng);
        }
        /* The throughput contributions are weighed by (hero MIS: the balance heuristic). */
        float3 beta_w = FEATURE_CHROMATIC && hero >= 0 ? beta * mis_weights(R) : beta;
        if (event == EVENT_CAPPED) break;
        if (event == EVENT_ESCAPE) {
            if (prm->has_env) {
                float w = depth > 0 ? mis_weight(prm->mis, pdf_phase, n_env) : 1.0f;
                L += beta_w * (env * w);
            }
            break;
        }
        depth += 1;
        if (prm->max_depth >= 0 && depth > prm->max_depth) break;
        counters[C_SCATTER] += 1;
        beta *= albedo;
        beta_w *= albedo;
        if (fmax(beta_w.x, fmax(beta_w.y, beta_w.z)) <= 0.0f) break;
        L += beta_w * sample_direct(prm, lights, med, ea, o, d, t0, t1, t, pix, s, depth - 1, rng,
                                    rng_s, counters);
        float3 p = o + t * d;
        if (depth >= prm->rr_depth) {
            float q = survival_probability(prm, beta_w, albedo);
            if (path_u1(prm, pix, s, bounce_pair(depth - 1, SAMPLER_FLIGHT), 1, 0u, 1u, rng) >= q)
                break;
            beta /= q;
        }
        float2 up = path_u2(prm, pix, s, bounce_pair(depth - 1, SAMPLER_PHASE), 0u, 1u, rng);
        d = phase_sample(m->phase_kind, m->g, up.x, up.y, d, &pdf_phase);
        o = p;
    }
    return L;
}

/* One work item per pixel of pixels [pix_start, pix_start + n_pix) (row-major indices: a
 * band of rows, or every pixel): samples [sample_start, sample_start + n_samples). Writes
 * the batch's per-pixel mean and sum of squared deviations (Welford's update, so a float32
 * batch keeps the variance accurate even when it is tiny next to the mean) at the pixel's
 * place in the launch, i = pix - pix_start, where its counters accumulate too; the host
 * turns them into float64 sums. A pixel's samples depend on its index alone, so any split
 * into bands gives the same image. A NaN, infinite or negative sample counts as 0 and is
 * counted as dropped, exactly as in the reference. */
kernel void render_batch(const Params prm, const Medium medium, global const Light *lights,
                         global const float *grid, global const float *maj,
                         global const float *mnr, global const float *emis,
                         global const float *table, global const int *bricks,
                         global const float *pool, global const int *nodes,
                         global float *rec, int rec_capacity, uint pix_start, uint n_pix,
                         uint sample_start, uint n_samples,
                         global float *out_mean, global float *out_m2,
                         global ulong *counters_out) {
    uint i_pix = get_global_id(0);
    if (i_pix >= n_pix) return;
    int pix = (int)(pix_start + i_pix);
    int py = pix / prm.width;
    int px = pix - py * prm.width;
    /* Pixel pix owns rows [pix (K + 1), (pix + 1) (K + 1)) of the record (K = rec_capacity);
     * without recording, rec is a 1-float dummy that nothing may index. */
    global float *rec_pix = FEATURE_RECORD && rec_capacity > 0
                                ? rec + (size_t)pix * (rec_capacity + 1) * RECORD_COLUMNS
                                : 0;
    MediumData med = {medium, grid, maj, mnr, emis, table, bricks, pool, nodes, rec_pix};
    ulong seed = ((ulong)prm.seed_hi << 32) | (ulong)prm.seed_lo;
    ulong cnt[N_COUNTERS];
    for (int k = 0; k < N_COUNTERS; ++k) cnt[k] = 0;
    float3 mean = (float3)(0.0f), m2 = (float3)(0.0f);
    Rng rng, rng_s;
    for (uint i = 0; i < n_samples; ++i) {
        rng_init(&rng, seed, (uint)pix, sample_start + i, STREAM_PATH);
        rng_init(&rng_s, seed, (uint)pix, sample_start + i, STREAM_SHADOW);
        float3 c = trace_path(&prm, lights, &med, px, py, sample_start + i, &rng, &rng_s, cnt);
        if (!sample_ok(c, prm.signed_samples)) {
            cnt[C_DROPPED] += 1;
            c = (float3)(0.0f);
        }
        float3 delta = c - mean;
        mean += delta / (float)(i + 1);
        m2 += delta * (c - mean);
    }
    vstore3(mean, i_pix, out_mean);
    vstore3(m2, i_pix, out_m2);
    for (int k = 0; k < N_COUNTERS; ++k) counters_out[(size_t)i_pix * N_COUNTERS + k] += cnt[k];
}
