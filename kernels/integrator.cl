/* Volumetric path tracer kernel. Twin of volmc/reference/integrator.py: the algorithm, the
 * order of random numbers and the Russian-roulette policy are described there.
 *
 * Built with -D flags derived from the scene (volmc/scene/features.py), so a scene pays
 * only for what it uses. A flag compiles a code path in; the parameters still decide at run
 * time whether it is taken, so a build with every flag on renders any scene (the "generic"
 * build the specialisation benchmark compares against). The flags:
 *   FEATURE_GRID          density from the grid (else homogeneous, analytic tracking)
 *   FEATURE_MAJORANT_GRID per-cell majorants along a 3-D DDA walk (render.majorant = "grid")
 *   FEATURE_PHASE_HG      Henyey-Greenstein phase function (else isotropic)
 *   FEATURE_ENV           an environment light (NEE by sphere sampling + MIS, escape term)
 *   FEATURE_DELTA_LIGHTS  directional and/or point lights in the light array
 *   FEATURE_POINT         point lights among them (else all directional)
 *   FEATURE_RR            Russian roulette can trigger (rr_depth below max_depth)
 *   FEATURE_ORTHO         orthographic camera (else perspective)
 *   FEATURE_SCATTER       scattering can reach the image (albedo > 0 and max_depth != 0);
 *                         without it a pixel is environment x transmittance
 * params.h (generated from volmc/params.py) defines Params, Light and the constants. */

#include "params.h"
#include "rng.h"
#include "sampling.h"
#include "phase.h"
#include "grid.h"
#include "transmittance.h"
#include "estimators.h"
#include "power_series.h"
#include "guards.h"

/* The shadow-ray estimator of grids (render.transmittance), chosen at build time. */
#ifndef SHADOW_ESTIMATOR
#define SHADOW_ESTIMATOR transmittance_ratio_tracking
#endif
#ifndef SHADOW_ESTIMATOR_EXTRA
#define SHADOW_ESTIMATOR_EXTRA
#endif

inline float3 vec3(const float v[3]) { return (float3)(v[0], v[1], v[2]); }
inline float3 vec3g(global const float v[3]) { return (float3)(v[0], v[1], v[2]); }

/* Returns t_enter, writes t_exit; no hit when t_enter >= t_exit. Zero direction components
 * (including -0.0) are handled without 0 * inf. */
inline float ray_box(float3 o, float3 d, float3 bmin, float3 bmax, float *t_exit) {
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

/* Guard "entry re-basing" (HARD_CASES 10, 11, 13): clips ray o + t d to the box and, when the
 * box is entered from outside (t_enter > 0), moves the origin to the entry point, snapped onto
 * the box (clamped into it, and exactly onto the entry face), and clips again from there.
 * Every later distance is then local to the box: no tracking loop accumulates a large t (a
 * far camera), the chord comes from nearby numbers (exact for a thin slab seen from afar),
 * and a dense medium is entered exactly at its face, never a rounding error inside it (which
 * would bury the path). Returns the origin to use; writes the local segment [*t0, *t1] (no
 * medium when *t1 <= *t0) and the distance *shift the origin moved along d. Twin of
 * enter_box in integrator.py. */
inline float3 enter_box(float3 o, float3 d, float3 bmin, float3 bmax, float *t0, float *t1,
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

inline float3 camera_ray(const Params *prm, int px, int py, float u1, float u2, float3 *dir) {
    float sx = (2.0f * ((float)px + u1) / (float)prm->width - 1.0f) * prm->half_height * prm->aspect;
    float sy = (1.0f - 2.0f * ((float)py + u2) / (float)prm->height) * prm->half_height;
    float3 f = vec3(prm->forward), r = vec3(prm->right), u = vec3(prm->up), e = vec3(prm->eye);
#ifdef FEATURE_ORTHO
    if (prm->cam_type == CAMERA_ORTHOGRAPHIC) {
        *dir = f;
        return e + sx * r + sy * u;
    }
#endif
    *dir = normalize(f + sx * r + sy * u);
    return e;
}

inline float shadow_transmittance(const Params *prm, global const float *med,
                                  global const float *grid, int3 dims, global const float *maj_max,
                                  global const float *maj_min, float3 o, float3 d, float t_max,
                                  Rng *rng_s, ulong *counters) {
    float3 bmin = vec3(prm->bmin), bmax = vec3(prm->bmax);
    float t0, t1, shift;
    o = enter_box(o, d, bmin, bmax, &t0, &t1, &shift);
    t1 = fmin(t1, t_max - shift);
    if (t1 <= t0) return 1.0f;
    counters[C_SHADOW] += 1;
#ifdef FEATURE_MAJORANT_GRID
    if (prm->has_grid && prm->has_majorant_grid) {
        /* Per DDA segment with the cell's bounds: a product of independent unbiased
         * estimates; empty cells give 1 with no lookup. */
        int3 res = (int3)(prm->maj_res[0], prm->maj_res[1], prm->maj_res[2]);
        Dda s;
        dda_init(&s, o, d, t0, t1, bmin, bmax, res);
        float T = 1.0f, ta, tb;
        int3 cell;
        while (dda_next(&s, &ta, &tb, &cell)) {
            int k = dda_cell_index(cell, res);
            float m = prm->scale * maj_max[k];
            if (m <= 0.0f || tb <= ta) continue;
            T *= SHADOW_ESTIMATOR(med, grid, dims, o, d, ta, tb, m, prm->scale * maj_min[k],
                                  rng_s, counters, prm->max_steps SHADOW_ESTIMATOR_EXTRA);
            /* Transmittance roulette over the product of segments (T == 0 ends it too). */
            if (!transmittance_roulette(&T, rng_s)) break;
        }
        return T;
    }
#endif
#ifdef FEATURE_GRID
    if (prm->has_grid)
        return SHADOW_ESTIMATOR(med, grid, dims, o, d, t0, t1, prm->majorant, prm->minorant,
                                rng_s, counters, prm->max_steps SHADOW_ESTIMATOR_EXTRA);
#endif
    return transmittance_homogeneous(prm->scale * prm->density, t0, t1);
}

inline float3 trace_path(const Params *prm, global const Light *lights, global const float *med,
                         global const float *grid, int3 dims, global const float *maj_max,
                         global const float *maj_min, int px, int py, Rng *rng, Rng *rng_s,
                         ulong *counters) {
    float3 bmin = vec3(prm->bmin), bmax = vec3(prm->bmax), inv_ext = vec3(prm->inv_extent);
    float3 env = vec3(prm->env);
    float3 L = (float3)(0.0f);
    float u1 = rng_next(rng);
    float u2 = rng_next(rng);
    float3 d;
    float3 o = camera_ray(prm, px, py, u1, u2, &d);
    float3 albedo = vec3(prm->albedo);
#ifdef FEATURE_SCATTER
    if (prm->max_depth == 0 || fmax(albedo.x, fmax(albedo.y, albedo.z)) <= 0.0f)
#endif
    {
#ifdef FEATURE_ENV
        if (prm->has_env)
            return env * shadow_transmittance(prm, med, grid, dims, maj_max, maj_min, o, d, NO_LIMIT, rng_s, counters);
#endif
        return L;
    }
#ifdef FEATURE_SCATTER
    float3 beta = (float3)(1.0f);
    int depth = 0;
    float pdf_phase = 0.0f;
    while (true) {
        float t0, t1, shift;
        o = enter_box(o, d, bmin, bmax, &t0, &t1, &shift);
        int event = EVENT_ESCAPE;
        float t = t1;
        if (t1 > t0) {
#ifdef FEATURE_MAJORANT_GRID
            if (prm->has_grid && prm->has_majorant_grid)
                event = free_flight_grid(
                    grid, dims, bmin, bmax, inv_ext, prm->scale, maj_max, maj_min,
                    prm->decomposition, (int3)(prm->maj_res[0], prm->maj_res[1], prm->maj_res[2]),
                    o, d, t0, t1, rng, counters, prm->max_steps, &t);
            else
#endif
#ifdef FEATURE_GRID
            if (prm->has_grid)
                event = free_flight_delta(grid, dims, bmin, inv_ext, prm->scale, prm->majorant,
                                          o, d, t0, t1, rng, counters, prm->max_steps, &t);
            else
#endif
                event = free_flight_homogeneous(prm->scale * prm->density, t0, t1, rng, &t);
        }
        if (event == EVENT_CAPPED) break;
        if (event == EVENT_ESCAPE) {
#ifdef FEATURE_ENV
            if (prm->has_env) {
                float w = depth > 0 ? pdf_phase / (pdf_phase + INV_4PI) : 1.0f;
                L += beta * env * w;
            }
#endif
            break;
        }
        depth += 1;
        if (prm->max_depth >= 0 && depth > prm->max_depth) break;
        counters[C_SCATTER] += 1;
        beta *= albedo;
        if (fmax(beta.x, fmax(beta.y, beta.z)) <= 0.0f) break;
        float3 p = o + t * d;
#ifdef FEATURE_DELTA_LIGHTS
        for (int i = 0; i < prm->n_lights; ++i) {
            float3 wl;
            float dist = NO_LIMIT, falloff = 1.0f;
#ifdef FEATURE_POINT
            if (lights[i].type == LIGHT_DIRECTIONAL) {
                wl = -vec3g(lights[i].vec);
            } else {
                float3 v = vec3g(lights[i].vec) - p;
                float dist2 = dot(v, v);
                if (dist2 <= 0.0f) continue;
                dist = sqrt(dist2);
                wl = v / dist;
                falloff = 1.0f / dist2;
            }
#else
            wl = -vec3g(lights[i].vec);
#endif
            float f = phase_eval(prm->phase_kind, prm->g, dot(d, wl)) * falloff;
            float tr = shadow_transmittance(prm, med, grid, dims, maj_max, maj_min, p, wl, dist, rng_s, counters);
            L += beta * (f * tr) * vec3g(lights[i].color);
        }
#endif
#ifdef FEATURE_ENV
        if (prm->has_env) {
            float ua = rng_next(rng);
            float ub = rng_next(rng);
            float pdf_l;
            float3 wl = sample_uniform_sphere(ua, ub, &pdf_l);
            float f = phase_eval(prm->phase_kind, prm->g, dot(d, wl));
            float tr = shadow_transmittance(prm, med, grid, dims, maj_max, maj_min, p, wl, NO_LIMIT, rng_s, counters);
            L += beta * (f * tr / (pdf_l + f)) * env;
        }
#endif
#ifdef FEATURE_RR
        if (depth >= prm->rr_depth) {
            float q = fmin(fmax(beta.x, fmax(beta.y, beta.z)), RR_MAX_SURVIVAL);
            if (rng_next(rng) >= q) break;
            beta /= q;
        }
#endif
        u1 = rng_next(rng);
        u2 = rng_next(rng);
        d = phase_sample(prm->phase_kind, prm->g, u1, u2, d, &pdf_phase);
        o = p;
    }
    return L;
#endif
}

/* One work item per pixel: samples [sample_start, sample_start + n_samples). Writes the
 * batch's per-pixel mean and sum of squared deviations (Welford's update, so a float32
 * batch keeps the variance accurate even when it is tiny next to the mean); the host turns
 * them into float64 sums. A NaN, infinite or negative sample counts as 0 and is counted
 * as dropped, exactly as in the reference. */
kernel void render_batch(const Params prm, global const Light *lights, global const float *med,
                         global const float *grid, int3 dims, global const float *maj_max,
                         global const float *maj_min, uint sample_start, uint n_samples,
                         global float *out_mean,
                         global float *out_m2, global ulong *counters_out) {
    int pix = get_global_id(0);
    if (pix >= prm.width * prm.height) return;
    int py = pix / prm.width;
    int px = pix - py * prm.width;
    ulong seed = ((ulong)prm.seed_hi << 32) | (ulong)prm.seed_lo;
    ulong cnt[N_COUNTERS];
    for (int k = 0; k < N_COUNTERS; ++k) cnt[k] = 0;
    float3 mean = (float3)(0.0f), m2 = (float3)(0.0f);
    Rng rng, rng_s;
    for (uint i = 0; i < n_samples; ++i) {
        rng_init(&rng, seed, (uint)pix, sample_start + i, STREAM_PATH);
        rng_init(&rng_s, seed, (uint)pix, sample_start + i, STREAM_SHADOW);
        float3 c = trace_path(&prm, lights, med, grid, dims, maj_max, maj_min, px, py, &rng, &rng_s,
                              cnt);
        if (!sample_ok(c, prm.signed_samples)) {
            cnt[C_DROPPED] += 1;
            c = (float3)(0.0f);
        }
        float3 delta = c - mean;
        mean += delta / (float)(i + 1);
        m2 += delta * (c - mean);
    }
    vstore3(mean, pix, out_mean);
    vstore3(m2, pix, out_m2);
    for (int k = 0; k < N_COUNTERS; ++k) counters_out[(size_t)pix * N_COUNTERS + k] += cnt[k];
}
