/* Numerical guards shared by the kernels. Twin of volmc/reference/guards.py.
 *
 * Guard "sample filter" (robustness case 20): a sample that is NaN, infinite or (unless the shadow
 * estimator is signed) negative is dropped and counted. The finiteness test reads the exponent
 * bits as an integer instead of calling isfinite(): -cl-fast-relaxed-math implies
 * -cl-finite-math-only, under which the compiler may fold isnan/isinf/isfinite to constants,
 * but integer operations are untouched. */
#ifndef VOLMC_GUARDS_H
#define VOLMC_GUARDS_H

/* "No limit" for distances (directional and environment shadow rays, slab starts): FLT_MAX
 * rather than INFINITY. Under -cl-finite-math-only an infinite operand is undefined and PoCL
 * folds it away: shadow rays with an INFINITY limit were skipped (T = 1, a biased image)
 * until the kernels used FLT_MAX. */
#define NO_LIMIT FLT_MAX

/* 1 unless x is NaN or +-Inf (all exponent bits set). */
static inline int finite_bits(float x) { return (as_uint(x) & 0x7f800000u) != 0x7f800000u; }

/* 1 if the sample may be accumulated. Negative zero is kept (it is a zero). */
static inline int sample_ok(float3 c, int signed_samples) {
    if (!(finite_bits(c.x) && finite_bits(c.y) && finite_bits(c.z))) return 0;
    return signed_samples || !(c.x < 0.0f || c.y < 0.0f || c.z < 0.0f);
}

#endif
