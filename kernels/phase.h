/* Phase functions: isotropic and Henyey-Greenstein. Twin of volmc/reference/phase.py, where
 * the convention (propagation directions, g > 0 forward) and the cancellation-free
 * inversion are derived. */
#ifndef VOLMC_PHASE_H
#define VOLMC_PHASE_H

#include "sampling.h"

/* PHASE_ISOTROPIC and PHASE_HG come from the generated params.h. */

static inline float hg_eval(float cos_theta, float g) {
    float denom = g >= 0.0f ? (1.0f - g) * (1.0f - g) + 2.0f * g * (1.0f - cos_theta)
                            : (1.0f + g) * (1.0f + g) - 2.0f * g * (1.0f + cos_theta);
    return INV_4PI * (1.0f - g) * (1.0f + g) / (denom * sqrt(denom));
}

/* Returns cos(theta); writes sin(theta) and the pdf (1/sr). */
static inline float hg_sample_cos(float u, float g, float *sin_theta, float *pdf) {
    float t = g >= 0.0f ? (1.0f - g) + 2.0f * g * u : (1.0f + g) - 2.0f * g * (1.0f - u);
    float inv_t2 = 1.0f / (t * t);
    float omc = (1.0f - g) * (1.0f - g) * (1.0f - u) * (1.0f + g + t) * inv_t2;
    float opc = (1.0f + g) * (1.0f + g) * u * (1.0f - g + t) * inv_t2;
    float c = omc < opc ? 1.0f - omc : opc - 1.0f;
    c = clamp(c, -1.0f, 1.0f);
    *sin_theta = sqrt(fmax(0.0f, omc * opc));
    float one_m_g2 = (1.0f - g) * (1.0f + g);
    *pdf = INV_4PI * t * t * t / (one_m_g2 * one_m_g2);
    return c;
}

static inline float3 hg_sample(float u1, float u2, float3 d_in, float g, float *pdf) {
    float sin_theta;
    float c = hg_sample_cos(u1, g, &sin_theta, pdf);
    return from_frame(d_in, c, sin_theta, TWO_PI * u2);
}

/* The uniform hg_sample_cos maps to cos_theta (derivation in phase.py). */
static inline float hg_invert_cos(float cos_theta, float g) {
    float denom = g >= 0.0f ? (1.0f - g) * (1.0f - g) + 2.0f * g * (1.0f - cos_theta)
                            : (1.0f + g) * (1.0f + g) - 2.0f * g * (1.0f + cos_theta);
    float s = sqrt(denom);
    return (1.0f - g) * (1.0f + cos_theta) / (s * (1.0f + g + s));
}

/* (u1, u2) that hg_sample maps to w about d_in. */
static inline float2 invert_hg_sample(float3 w, float3 d_in, float g) {
    float c = clamp(dot(d_in, w), -1.0f, 1.0f);
    float3 s, t;
    coordinate_system(d_in, &s, &t);
    float phi = atan2(dot(w, t), dot(w, s));
    if (phi < 0.0f) phi += TWO_PI;
    return (float2)(hg_invert_cos(c, g), phi / TWO_PI);
}

static inline float phase_eval(int kind, float g, float cos_theta) {
    if (kind == PHASE_HG) return hg_eval(cos_theta, g);
    return INV_4PI;
}

static inline float3 phase_sample(int kind, float g, float u1, float u2, float3 d_in, float *pdf) {
    if (kind == PHASE_HG) return hg_sample(u1, u2, d_in, g, pdf);
    return sample_uniform_sphere(u1, u2, pdf);
}

#endif
