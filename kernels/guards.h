/* Numerical guards shared by the kernels. Twin of volmc/reference/guards.py.
 *
 * Guard "sample filter" (robustness case 20): a sample that is NaN, infinite or (unless the shadow
 * estimator is signed) negative is dropped and counted. The finiteness test reads the exponent
 * bits as an integer instead of calling isfinite(): -cl-fast-relaxed-math implies
 * -cl-finite-math-only, under which the compiler may fold isnan/isinf/isfinite to constants,
 * but integer operations are untouched. */
#ifndef VOLMC_GUARDS_H
#define VOLMC_GUARDS_H

#include "lanes.h"

/* "No limit" for distances (directional and environment shadow rays, slab starts): FLT_MAX
 * rather than INFINITY. Under -cl-finite-math-only an infinite operand is undefined and PoCL
 * folds it away: shadow rays with an INFINITY limit were skipped (T = 1, a biased image)
 * until the kernels used FLT_MAX. */
#define NO_LIMIT FLT_MAX

/* True (a lane mask) unless x is NaN or +-Inf (all exponent bits set). */
static inline lmask finite_bits(lfloat x) { return (as_luint(x) & 0x7f800000u) != 0x7f800000u; }

/* True (a lane mask) where the sample may be accumulated. Negative zero is kept (it is a
 * zero). */
static inline lmask sample_ok(lvec3 c, int signed_samples) {
    lmask finite = finite_bits(c.x) & finite_bits(c.y) & finite_bits(c.z);
    if (signed_samples) return finite;
    return finite & !(c.x < 0.0f || c.y < 0.0f || c.z < 0.0f);
}

#endif
