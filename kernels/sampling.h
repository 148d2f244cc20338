/* Sampling warps: pure functions of explicit uniforms. Twin of volmc/reference/sampling.py.
 * Where the reference returns (sample, pdf), the kernel returns the sample and writes the
 * pdf through the last argument. Directions are lvec3 unit vectors, one per lane; a branch
 * of the reference is a select between both results, so every lane computes both. */
#ifndef VOLMC_SAMPLING_H
#define VOLMC_SAMPLING_H

#include "params.h" /* INV_4PI, INV_PI, PI_OVER_2, PI_OVER_4, TWO_PI (volmc/constants.py) */
#include "lanes.h"
#include "guards.h" /* NO_LIMIT */

static inline lfloat sample_exponential(lfloat u, lfloat a, lfloat *pdf) {
    lmask none = a <= 0.0f; /* no collision: NO_LIMIT, math.inf in the Numba twin */
    *pdf = select(a * (1.0f - u), (lfloat)(0.0f), none); /* a e^{-a t} at t, without an exp */
    return select(-log1p(-u) / a, (lfloat)(NO_LIMIT), none);
}

static inline lfloat exponential_pdf(lfloat t, lfloat a) {
    return select(a * exp(-a * t), (lfloat)(0.0f), a <= 0.0f || t < 0.0f);
}

static inline lfloat invert_exponential_sample(lfloat t, lfloat a) { return -expm1(-a * t); }

static inline lvec3 sample_uniform_sphere(lfloat u1, lfloat u2, lfloat *pdf) {
    lfloat z = 1.0f - 2.0f * u1;
    lfloat r = sqrt(fmax(0.0f, 1.0f - z * z));
    lfloat phi = TWO_PI * u2;
    *pdf = INV_4PI;
    lfloat c, s = sincos(phi, &c); /* PoCL's sin and cos bit for bit, and cheaper */
    return v3(r * c, r * s, z);
}

static inline float uniform_sphere_pdf(void) { return INV_4PI; }

/* (u1, u2) that sample_uniform_sphere maps to w. */
static inline lvec2 invert_uniform_sphere(lvec3 w) {
    lfloat phi = atan2(w.y, w.x);
    phi = select(phi, phi + TWO_PI, phi < 0.0f);
    lvec2 u = {0.5f * (1.0f - w.z), phi / TWO_PI};
    return u;
}

/* Shirley-Chiu concentric mapping of the square onto the unit disc (twin in sampling.py). */
static inline lvec2 sample_uniform_disc(lfloat u1, lfloat u2, lfloat *pdf) {
    lfloat a = 2.0f * u1 - 1.0f, b = 2.0f * u2 - 1.0f;
    lmask wide = fabs(a) > fabs(b);
    lfloat r = select(b, a, wide);
    lfloat q = select(a, b, wide) / select(r, (lfloat)(1.0f), r == 0.0f); /* no 0 / 0 */
    lfloat phi = select(PI_OVER_2 - PI_OVER_4 * q, PI_OVER_4 * q, wide);
    lfloat c, s = sincos(phi, &c);
    *pdf = INV_PI;
    lvec2 p = {r * c, r * s};
    return p;
}

static inline float uniform_disc_pdf(void) { return INV_PI; }

/* (u1, u2) that sample_uniform_disc maps to p. */
static inline lvec2 invert_uniform_disc(lvec2 p) {
    lfloat r = sqrt(p.x * p.x + p.y * p.y);
    lmask wide = fabs(p.x) > fabs(p.y);
    lfloat num = select(p.x, p.y, wide), den = select(p.y, p.x, wide);
    lfloat axis = copysign(r, den);
    lfloat other = axis * atan(num / select(den, (lfloat)(1.0f), den == 0.0f)) / PI_OVER_4;
    lmask origin = r == 0.0f;
    lvec2 u = {select(0.5f * (select(other, axis, wide) + 1.0f), (lfloat)(0.5f), origin),
               select(0.5f * (select(axis, other, wide) + 1.0f), (lfloat)(0.5f), origin)};
    return u;
}

/* Duff et al. 2017 orthonormal basis; s and t written through the pointers. */
static inline void coordinate_system(lvec3 n, lvec3 *s, lvec3 *t) {
    lfloat sign = copysign((lfloat)(1.0f), n.z);
    lfloat a = -1.0f / (sign + n.z);
    lfloat b = n.x * n.y * a;
    *s = v3(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    *t = v3(b, sign + n.y * n.y * a, -n.y);
}

static inline lvec3 from_frame(lvec3 n, lfloat cos_theta, lfloat sin_theta, lfloat phi) {
    lvec3 s, t;
    coordinate_system(n, &s, &t);
    /* sincos: 1.05x samples/s on the default cloud at W = 16, 1.03x at W = 1, same image */
    lfloat cp, sp = sincos(phi, &cp);
    return add3(add3(scale3(s, cp * sin_theta), scale3(t, sp * sin_theta)),
                scale3(n, cos_theta));
}

/* Uniform direction in the cone about unit axis with 1 - cos theta_max = omc (twin of
 * sample_cone in sampling.py, which says why omc); writes the pdf 1 / (2 pi omc). */
static inline lvec3 sample_cone(lfloat u1, lfloat u2, lvec3 axis, lfloat omc, lfloat *pdf) {
    lfloat x = u1 * omc;
    *pdf = 1.0f / (TWO_PI * omc);
    return from_frame(axis, 1.0f - x, sqrt(fmax(0.0f, x * (2.0f - x))), TWO_PI * u2);
}

/* Density of sample_cone at unit w: 0 outside the cone (1 - cos theta = |w - axis|^2 / 2). */
static inline lfloat cone_pdf(lvec3 w, lvec3 axis, lfloat omc) {
    lvec3 v = sub3(w, axis);
    return select(1.0f / (TWO_PI * omc), (lfloat)(0.0f), 0.5f * dot3(v, v) > omc);
}

/* (u1, u2) that sample_cone maps to w. */
static inline lvec2 invert_cone(lvec3 w, lvec3 axis, lfloat omc) {
    lvec3 v = sub3(w, axis), s, t;
    coordinate_system(axis, &s, &t);
    lfloat phi = atan2(dot3(w, t), dot3(w, s));
    phi = select(phi, phi + TWO_PI, phi < 0.0f);
    lvec2 u = {0.5f * dot3(v, v) / omc, phi / TWO_PI};
    return u;
}

/* Balance-heuristic weight of strategy a against b, one sample each (Veach 1997). */
static inline lfloat mis_balance(lfloat pdf_a, lfloat pdf_b) { return pdf_a / (pdf_a + pdf_b); }

/* Power heuristic, exponent 2 (twin in sampling.py). */
static inline lfloat mis_power(lfloat pdf_a, lfloat pdf_b) {
    lfloat a = pdf_a * pdf_a;
    return a / (a + pdf_b * pdf_b);
}

static inline lfloat mis_weight(int kind, lfloat pdf_a, lfloat pdf_b) {
    return kind == MIS_POWER ? mis_power(pdf_a, pdf_b) : mis_balance(pdf_a, pdf_b);
}

/* The weight of strategy a against b divided by pdf_a, without dividing by pdf_a (twin in
 * sampling.py): finite where pdf_a is tiny or 0 beside pdf_b. */
static inline lfloat mis_weight_over(int kind, lfloat pdf_a, lfloat pdf_b) {
    if (kind != MIS_POWER) return 1.0f / (pdf_a + pdf_b);
    lfloat m = fmax(pdf_a, pdf_b), a = pdf_a / m, b = pdf_b / m;
    return a / ((a * a + b * b) * m);
}

/* Equiangular distance sampling towards a point (Kulla & Fajardo 2012; twins of
 * equiangular_side, equiangular_angle, equiangular_uniform, sample_equiangular,
 * equiangular_pdf and invert_equiangular_sample in sampling.py, where the arguments and the
 * two ways of measuring the angle are described): t in [ta, tb]. */
static inline lint equiangular_side(lfloat h, lfloat ta, lfloat tb) {
    return select(select((lint)(0), (lint)(-1), tb - h <= 0.0f), (lint)(1), ta - h >= 0.0f);
}

static inline lfloat equiangular_angle(lfloat t, lfloat h, lfloat D, lint side) {
    lfloat x = t - h;
    lmask one = side != 0;
    return atan2(select(x, D, one), select(D, to_lfloat(side) * x, one));
}

static inline lmask equiangular_uniform(lfloat a, lfloat b) {
    return !(fabs(b - a) > EQUIANGULAR_MIN_WIDTH * fmax(fabs(a), fabs(b)));
}

static inline lfloat equiangular_pdf(lfloat t, lfloat h, lfloat D, lfloat ta, lfloat tb) {
    lint side = equiangular_side(h, ta, tb);
    lfloat a = equiangular_angle(ta, h, D, side), b = equiangular_angle(tb, h, D, side);
    lfloat x = t - h;
    lfloat p = select(D / (fabs(b - a) * (D * D + x * x)), 1.0f / (tb - ta),
                      equiangular_uniform(a, b));
    return select(p, (lfloat)(0.0f), t < ta || t > tb || !(tb > ta));
}

static inline lfloat sample_equiangular(lfloat u, lfloat h, lfloat D, lfloat ta, lfloat tb,
                                        lfloat *pdf) {
    lint side = equiangular_side(h, ta, tb);
    lfloat a = equiangular_angle(ta, h, D, side), b = equiangular_angle(tb, h, D, side);
    lmask uniform = equiangular_uniform(a, b);
    lfloat tn = tan(a + u * (b - a));
    lfloat t = clamp(h + select(D * tn, to_lfloat(side) * (D / tn), side != 0), ta, tb);
    lfloat x = t - h;
    *pdf = select(D / (fabs(b - a) * (D * D + x * x)),
                  select((lfloat)(0.0f), 1.0f / (tb - ta), tb > ta), uniform);
    return select(t, ta + u * (tb - ta), uniform);
}

static inline lfloat invert_equiangular_sample(lfloat t, lfloat h, lfloat D, lfloat ta,
                                               lfloat tb) {
    lint side = equiangular_side(h, ta, tb);
    lfloat a = equiangular_angle(ta, h, D, side), b = equiangular_angle(tb, h, D, side);
    return select((equiangular_angle(t, h, D, side) - a) / (b - a), (t - ta) / (tb - ta),
                  equiangular_uniform(a, b));
}

#endif
