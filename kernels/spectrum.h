/* The type of per-channel weights in the tracking loop (transmittance estimates, spectral
 * tracking's flight weights): `spec` is RGB (lvec3) per lane when the build has
 * colour-dependent extinction (FEATURE_CHROMATIC) and one lfloat otherwise, so a grey scene
 * runs the scalar arithmetic it always ran. `uspec` is the same for a value every lane
 * shares (the medium's chroma): float3 or float. The reference always carries RGB tuples
 * (volmc/reference/vec.py); for a grey medium its three channels are equal, and the
 * kernels' one value is any of them. The spec_* helpers are the few operations the tracking
 * loop and the estimators write on a spec. */
#ifndef VOLMC_SPECTRUM_H
#define VOLMC_SPECTRUM_H

#include "features.h"
#include "lanes.h"

#if FEATURE_CHROMATIC
typedef lvec3 spec;
typedef float3 uspec;
static inline lfloat spec_max(spec a) { return max3(a); }
static inline lvec3 spec_rgb(spec a) { return a; }
static inline lfloat spec_first(spec a) { return a.x; }
static inline spec spec_s(lfloat s) { return v3s(s); }
static inline spec spec_u(uspec k) { return v3u(k); }
static inline spec spec_add(spec a, spec b) { return add3(a, b); }
static inline spec spec_sub(spec a, spec b) { return sub3(a, b); }
static inline spec spec_div(spec a, lfloat s) { return div3(a, s); }
static inline spec spec_mul(spec a, spec b) { return mul3(a, b); }
static inline spec spec_scale(spec a, lfloat s) { return scale3(a, s); }
static inline spec spec_sel(spec a, spec b, lmask m) { return sel3(a, b, m); }
static inline spec spec_abs(spec a) { return v3(fabs(a.x), fabs(a.y), fabs(a.z)); }
/* exp(-k s) per channel of k, for s per lane (exp_neg3 in vec.py). */
static inline spec spec_exp_neg(uspec k, lfloat s) {
    return v3(exp(-(k.x * s)), exp(-(k.y * s)), exp(-(k.z * s)));
}
/* a (1 - k s) per channel of k (mul_one_minus3 in vec.py), as a - a (k s) in one rounding:
 * a ratio-tracking step. 1 - k s rounded to float32 errs by the same amount at every step
 * through constant density, so over the 1e5 steps of a far too high majorant the error added
 * up to a bias of 1 %; the fused step's rounding varies from step to step. */
static inline spec spec_mul_one_minus(spec a, uspec k, lfloat s) {
    return v3(fma(-a.x, k.x * s, a.x), fma(-a.y, k.y * s, a.y), fma(-a.z, k.z * s, a.z));
}
#else
typedef lfloat spec;
typedef float uspec;
static inline lfloat spec_max(spec a) { return a; }
static inline lvec3 spec_rgb(spec a) { return v3s(a); }
static inline lfloat spec_first(spec a) { return a; }
static inline spec spec_s(lfloat s) { return s; }
static inline spec spec_u(uspec k) { return (lfloat)(k); }
static inline spec spec_add(spec a, spec b) { return a + b; }
static inline spec spec_sub(spec a, spec b) { return a - b; }
static inline spec spec_div(spec a, lfloat s) { return a / s; }
static inline spec spec_mul(spec a, spec b) { return a * b; }
static inline spec spec_scale(spec a, lfloat s) { return a * s; }
static inline spec spec_sel(spec a, spec b, lmask m) { return select(a, b, m); }
static inline spec spec_abs(spec a) { return fabs(a); }
static inline spec spec_exp_neg(uspec k, lfloat s) { return exp(-(k * s)); }
static inline spec spec_mul_one_minus(spec a, uspec k, lfloat s) { return fma(-a, k * s, a); }
#endif

#endif
