/* Phase functions: isotropic and Henyey-Greenstein. Twin of volmc/reference/phase.py, where
 * the convention (propagation directions, g > 0 forward) and the cancellation-free
 * inversion are derived. g and the kind are the medium's, the same in every lane. */
#ifndef VOLMC_PHASE_H
#define VOLMC_PHASE_H

#include "lanes.h"
#include "sampling.h"

/* PHASE_ISOTROPIC and PHASE_HG come from the generated params.h. */

/* 1 + g^2 - 2 g cos as a sum of non-negative terms (twin in phase.py): side is 1 - cos for
 * g >= 0, 1 + cos for g < 0. */
static inline lfloat hg_denom(lfloat side, float g) {
    float a = fabs(g);
    return (1.0f - a) * (1.0f - a) + 2.0f * a * side;
}

/* HG (1/sr) from its hg_denom. */
static inline lfloat hg_value(lfloat denom, float g) {
    return INV_4PI * (1.0f - g) * (1.0f + g) / (denom * sqrt(denom));
}

static inline lfloat hg_eval(lfloat cos_theta, float g) {
    return hg_value(hg_denom(g >= 0.0f ? 1.0f - cos_theta : 1.0f + cos_theta, g), g);
}

/* Returns cos(theta); writes sin(theta) and the pdf (1/sr). */
static inline lfloat hg_sample_cos(lfloat u, float g, lfloat *sin_theta, lfloat *pdf) {
    lfloat t = g >= 0.0f ? (1.0f - g) + 2.0f * g * u : (1.0f + g) - 2.0f * g * (1.0f - u);
    lfloat inv_t2 = 1.0f / (t * t);
    lfloat omc = (1.0f - g) * (1.0f - g) * (1.0f - u) * (1.0f + g + t) * inv_t2;
    lfloat opc = (1.0f + g) * (1.0f + g) * u * (1.0f - g + t) * inv_t2;
    lfloat c = select(opc - 1.0f, 1.0f - omc, omc < opc);
    c = clamp(c, -1.0f, 1.0f);
    *sin_theta = sqrt(fmax(0.0f, omc * opc));
    float one_m_g2 = (1.0f - g) * (1.0f + g);
    *pdf = INV_4PI * t * t * t / (one_m_g2 * one_m_g2);
    return c;
}

static inline lvec3 hg_sample(lfloat u1, lfloat u2, lvec3 d_in, float g, lfloat *pdf) {
    lfloat sin_theta;
    lfloat c = hg_sample_cos(u1, g, &sin_theta, pdf);
    return from_frame(d_in, c, sin_theta, TWO_PI * u2);
}

/* The uniform hg_sample_cos maps to cos_theta (derivation in phase.py). */
static inline lfloat hg_invert_cos(lfloat cos_theta, float g) {
    lfloat s = sqrt(hg_denom(g >= 0.0f ? 1.0f - cos_theta : 1.0f + cos_theta, g));
    return (1.0f - g) * (1.0f + cos_theta) / (s * (1.0f + g + s));
}

/* (u1, u2) that hg_sample maps to w about d_in. */
static inline lvec2 invert_hg_sample(lvec3 w, lvec3 d_in, float g) {
    lfloat c = clamp(dot3(d_in, w), -1.0f, 1.0f);
    lvec3 s, t;
    coordinate_system(d_in, &s, &t);
    lfloat phi = atan2(dot3(w, t), dot3(w, s));
    phi = select(phi, phi + TWO_PI, phi < 0.0f);
    lvec2 u = {hg_invert_cos(c, g), phi / TWO_PI};
    return u;
}

/* HG at the angle between unit directions d and w (twin in phase.py, which says why not
 * from their cosine). */
static inline lfloat hg_eval_dirs(lvec3 d, lvec3 w, float g) {
    lvec3 c = g >= 0.0f ? sub3(w, d) : add3(w, d);
    return hg_value(hg_denom(0.5f * dot3(c, c), g), g); /* 1 - cos, or 1 + cos */
}

/* The phase function at the angle between unit directions d (the path's) and w. */
static inline lfloat phase_eval(int kind, float g, lvec3 d, lvec3 w) {
    if (kind == PHASE_HG) return hg_eval_dirs(d, w, g);
    return (lfloat)(INV_4PI);
}

static inline lvec3 phase_sample(int kind, float g, lfloat u1, lfloat u2, lvec3 d_in,
                                 lfloat *pdf) {
    if (kind == PHASE_HG) return hg_sample(u1, u2, d_in, g, pdf);
    return sample_uniform_sphere(u1, u2, pdf);
}

#endif
