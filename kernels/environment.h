/* Environment maps: radiance from a lat-long image and the sampler that draws directions in
 * proportion to it. Twin of volmc/reference/environment.py, which states the conventions
 * (Mitsuba 3's). The map's arrays lie one after another in `env` (pack.env_buffer): texels
 * [H][W][3], pdf [H][W], marginal [H + 1], conditional [H][W + 1], with (W, H) = env_res. */
#ifndef VOLMC_ENVIRONMENT_H
#define VOLMC_ENVIRONMENT_H

#include "params.h"
#include "lanes.h"

/* sin(pi v) for v in [0, 1], from the nearer pole (reference: env_sin_theta). */
static inline lfloat env_sin_theta(lfloat v) {
    return sin(PI * fmin(v, 1.0f - v));
}

/* The map-frame direction of texture coordinates (u, v); theta from the nearer pole. */
static inline lvec3 env_direction(lfloat u, lfloat v) {
    lfloat cp, sp = sincos(TWO_PI * u, &cp);
    lfloat ct, st = sincos(PI * fmin(v, 1.0f - v), &ct);
    return v3(sp * st, select(ct, -ct, v > 0.5f), -cp * st);
}

/* Texture coordinates (u, v) of map-frame unit direction w; writes sin theta. atan2, not
 * acos(w.y), which is 0 or pi within 2.4e-4 rad of a pole in float32 (environment.py). */
static inline lvec2 env_uv_sin(lvec3 w, lfloat *sin_theta) {
    lfloat phi = atan2(w.x, -w.z);
    phi = select(phi, phi + TWO_PI, phi < 0.0f);
    *sin_theta = sqrt(w.x * w.x + w.z * w.z);
    lvec2 uv = {phi / TWO_PI, atan2(*sin_theta, w.y) / PI};
    return uv;
}

static inline lvec2 env_uv(lvec3 w) {
    lfloat s;
    return env_uv_sin(w, &s);
}

/* Scene direction w in the map's frame, and back. */
static inline lvec3 env_to_map(const Params *prm, lvec3 w) {
    const float *r = prm->env_rot;
    return v3(r[0] * w.x + r[1] * w.y + r[2] * w.z, r[3] * w.x + r[4] * w.y + r[5] * w.z,
              r[6] * w.x + r[7] * w.y + r[8] * w.z);
}

static inline lvec3 env_from_map(const Params *prm, lvec3 m) {
    const float *r = prm->env_rot;
    return v3(r[0] * m.x + r[3] * m.y + r[6] * m.z, r[1] * m.x + r[4] * m.y + r[7] * m.z,
              r[2] * m.x + r[5] * m.y + r[8] * m.z);
}

/* Index row W + column of the texel holding (u, v); writes its row. Clamped on both sides:
 * lanes not in use may hold any direction, NaN included, and still read inside the map. */
static inline lint env_texel(const Params *prm, lfloat u, lfloat v, lint *row) {
    int w = prm->env_res[0], h = prm->env_res[1];
    *row = clamp(to_lint_rtz(v * (float)h), 0, h - 1);
    return *row * w + clamp(to_lint_rtz(u * (float)w), 0, w - 1);
}

/* Radiance arriving from scene direction w (unit), RGB. */
static inline lvec3 env_radiance(const Params *prm, global const float *env, lvec3 w) {
    lvec2 uv = env_uv(env_to_map(prm, w));
    lint row;
    lint k = 3 * env_texel(prm, uv.x, uv.y, &row);
    float3 e = (float3)(prm->env[0], prm->env[1], prm->env[2]);
    return v3(e.x * gather_float(env, k), e.y * gather_float(env, k + 1),
              e.z * gather_float(env, k + 2));
}

/* The largest i in [0, n - 1] with cdf[base + i] <= x (a CDF of n + 1 entries from 0 to 1,
 * x in [0, 1)), by bisection; the lanes bisect together. */
static inline lint cdf_find(global const float *cdf, lint base, int n, lfloat x,
                            lmask active) {
    lint lo = (lint)(0), hi = (lint)(n);
    lmask more = active & (hi - lo > 1);
    while (ANY(more)) {
        lint mid = (lo + hi) >> 1;
        lmask below = gather_float(cdf, base + select((lint)(0), mid, more)) <= x;
        lo = select(lo, mid, more & below);
        hi = select(hi, mid, more & !below);
        more = more & (hi - lo > 1);
    }
    return lo;
}

/* A scene direction from the map's density; writes its pdf per steradian. */
static inline lvec3 sample_environment(const Params *prm, global const float *env, lfloat u1,
                                       lfloat u2, lfloat *pdf, lmask active) {
    int w = prm->env_res[0], h = prm->env_res[1];
    global const float *pdfs = env + 3 * w * h, *marginal = pdfs + w * h;
    global const float *conditional = marginal + h + 1;
    lint r = cdf_find(marginal, (lint)(0), h, u1, active);
    lfloat a = gather_float(marginal, r), b = gather_float(marginal, r + 1);
    lfloat v = (to_lfloat(r) + fmin((u1 - a) / (b - a), 1.0f)) / (float)h;
    lint base = r * (w + 1);
    lint c = cdf_find(conditional, base, w, u2, active);
    a = gather_float(conditional, base + c);
    b = gather_float(conditional, base + c + 1);
    lfloat u = (to_lfloat(c) + fmin((u2 - a) / (b - a), 1.0f)) / (float)w;
    lfloat s = env_sin_theta(v);
    *pdf = select((lfloat)(0.0f), gather_float(pdfs, r * w + c) / (2.0f * PI * PI * s),
                  s > 0.0f);
    return env_from_map(prm, env_direction(u, v));
}

/* Density per steradian of sample_environment at scene direction w (unit). */
static inline lfloat environment_pdf(const Params *prm, global const float *env, lvec3 w) {
    lfloat s;
    lvec2 uv = env_uv_sin(env_to_map(prm, w), &s);
    lint row;
    lint k = env_texel(prm, uv.x, uv.y, &row);
    global const float *pdfs = env + 3 * prm->env_res[0] * prm->env_res[1];
    return select((lfloat)(0.0f), gather_float(pdfs, k) / (2.0f * PI * PI * s), s > 0.0f);
}

/* (u1, u2) that sample_environment maps to scene direction w (unit). */
static inline lvec2 invert_environment(const Params *prm, global const float *env, lvec3 w) {
    int wd = prm->env_res[0], h = prm->env_res[1];
    global const float *marginal = env + 4 * wd * h, *conditional = marginal + h + 1;
    lvec2 uv = env_uv(env_to_map(prm, w));
    lint r;
    lint c = env_texel(prm, uv.x, uv.y, &r) - r * wd;
    lfloat a = gather_float(marginal, r), b = gather_float(marginal, r + 1);
    lvec2 out;
    out.x = a + (uv.y * (float)h - to_lfloat(r)) * (b - a);
    lint base = r * (wd + 1);
    a = gather_float(conditional, base + c);
    b = gather_float(conditional, base + c + 1);
    out.y = a + (uv.x * (float)wd - to_lfloat(c)) * (b - a);
    return out;
}

#endif
