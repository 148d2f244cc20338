"""Numerical guards shared by the reference (twin of kernels/guards.h).

Guard "sample filter" (robustness case 20): a sample that is NaN, infinite or (unless the shadow
estimator is signed) negative is dropped and counted. Finiteness is read from the exponent
bits as an integer, not with math.isfinite: under fast-math (Numba ``fastmath=True``, OpenCL
``-cl-fast-relaxed-math``) the compiler may assume no NaN or Inf exists and fold
isnan/isinf/isfinite to constants (tests/hard/test_case20_fastmath.py shows Numba does), while
integer operations are untouched. ``sample_ok`` is inlined into its caller, so it is compiled
with the caller's flags; the bit test survives them.
"""

import numpy as np
from numba import njit, types
from numba.core.extending import intrinsic

_EXP64 = np.uint64(0x7FF0000000000000)
_F32_MAX = float(np.finfo(np.float32).max)


@intrinsic
def f64_bits(typingctx, x):
    """The IEEE-754 bits of a float64 as a uint64 (an LLVM bitcast, no arithmetic)."""
    sig = types.uint64(types.float64)

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.uint64))
    return sig, codegen


@njit(cache=True, inline="always")
def finite_bits(x):
    """True unless x is NaN or +-Inf (all exponent bits set)."""
    return (f64_bits(x) & _EXP64) != _EXP64


@njit(cache=True, inline="always")
def sample_ok(r, g, b, signed_samples):
    """True if the sample (r, g, b) may be accumulated. Negative zero is kept (it is a zero).
    A component past float32's range is not finite in the kernels, so the twins drop it alike
    (kept, it made the image's float32 EXR infinite: a point light of intensity 3e38)."""
    if not (finite_bits(r) and finite_bits(g) and finite_bits(b)):
        return False
    if not (abs(r) <= _F32_MAX and abs(g) <= _F32_MAX and abs(b) <= _F32_MAX):
        return False
    return signed_samples != 0 or not (r < 0.0 or g < 0.0 or b < 0.0)
