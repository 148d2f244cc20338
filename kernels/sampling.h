/* Sampling warps: pure functions of explicit uniforms. Twin of volmc/reference/sampling.py.
 * Where the reference returns (sample, pdf), the kernel returns the sample and writes the
 * pdf through the last argument. Directions are float3 unit vectors. */
#ifndef VOLMC_SAMPLING_H
#define VOLMC_SAMPLING_H

#include "params.h" /* INV_4PI, TWO_PI (volmc/constants.py) */
#include "guards.h" /* NO_LIMIT */

static inline float sample_exponential(float u, float a, float *pdf) {
    if (a <= 0.0f) {
        *pdf = 0.0f;
        return NO_LIMIT; /* no collision; math.inf in the Numba twin (volmc/constants.py) */
    }
    float t = -log1p(-u) / a;
    *pdf = a * (1.0f - u); /* a e^{-a t} at the sampled t, without an exp */
    return t;
}

static inline float exponential_pdf(float t, float a) {
    if (a <= 0.0f || t < 0.0f) return 0.0f;
    return a * exp(-a * t);
}

static inline float invert_exponential_sample(float t, float a) { return -expm1(-a * t); }

static inline float3 sample_uniform_sphere(float u1, float u2, float *pdf) {
    float z = 1.0f - 2.0f * u1;
    float r = sqrt(fmax(0.0f, 1.0f - z * z));
    float phi = TWO_PI * u2;
    *pdf = INV_4PI;
    return (float3)(r * cos(phi), r * sin(phi), z);
}

static inline float uniform_sphere_pdf(void) { return INV_4PI; }

/* (u1, u2) that sample_uniform_sphere maps to w. */
static inline float2 invert_uniform_sphere(float3 w) {
    float phi = atan2(w.y, w.x);
    if (phi < 0.0f) phi += TWO_PI;
    return (float2)(0.5f * (1.0f - w.z), phi / TWO_PI);
}

/* Duff et al. 2017 orthonormal basis; s and t written through the pointers. */
static inline void coordinate_system(float3 n, float3 *s, float3 *t) {
    float sign = copysign(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float b = n.x * n.y * a;
    *s = (float3)(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    *t = (float3)(b, sign + n.y * n.y * a, -n.y);
}

static inline float3 from_frame(float3 n, float cos_theta, float sin_theta, float phi) {
    float3 s, t;
    coordinate_system(n, &s, &t);
    return (cos(phi) * sin_theta) * s + (sin(phi) * sin_theta) * t + cos_theta * n;
}

/* Balance-heuristic weight of strategy a against b, one sample each (Veach 1997). */
static inline float mis_balance(float pdf_a, float pdf_b) { return pdf_a / (pdf_a + pdf_b); }

/* Power heuristic, exponent 2 (twin in sampling.py). */
static inline float mis_power(float pdf_a, float pdf_b) {
    float a = pdf_a * pdf_a;
    return a / (a + pdf_b * pdf_b);
}

static inline float mis_weight(int kind, float pdf_a, float pdf_b) {
    return kind == MIS_POWER ? mis_power(pdf_a, pdf_b) : mis_balance(pdf_a, pdf_b);
}

/* Equiangular distance sampling towards a point (Kulla & Fajardo 2012; twin of
 * sample_equiangular in sampling.py, where the arguments are described): t in [ta, tb]. */
static inline float equiangular_pdf(float t, float h, float D, float ta, float tb) {
    if (t < ta || t > tb || !(tb > ta)) return 0.0f;
    float th_a = atan2(ta - h, D), th_b = atan2(tb - h, D);
    if (!(th_b > th_a)) return 1.0f / (tb - ta); /* angles equal to rounding: uniform */
    float x = t - h;
    return D / ((th_b - th_a) * (D * D + x * x));
}

static inline float sample_equiangular(float u, float h, float D, float ta, float tb, float *pdf) {
    float th_a = atan2(ta - h, D), th_b = atan2(tb - h, D);
    if (!(th_b > th_a)) {
        *pdf = tb > ta ? 1.0f / (tb - ta) : 0.0f;
        return ta + u * (tb - ta);
    }
    float t = clamp(h + D * tan(th_a + u * (th_b - th_a)), ta, tb);
    float x = t - h;
    *pdf = D / ((th_b - th_a) * (D * D + x * x));
    return t;
}

static inline float invert_equiangular_sample(float t, float h, float D, float ta, float tb) {
    float th_a = atan2(ta - h, D), th_b = atan2(tb - h, D);
    if (!(th_b > th_a)) return (t - ta) / (tb - ta);
    return (atan2(t - h, D) - th_a) / (th_b - th_a);
}

#endif
