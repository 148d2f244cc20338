"""3-vectors and RGB triples as tuples: the few operations the kernels write with float3."""

import math

from numba import njit


@njit(cache=True, inline="always")
def add3(a, b):
    """a + b."""
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@njit(cache=True, inline="always")
def mul3(a, b):
    """Componentwise a * b."""
    return (a[0] * b[0], a[1] * b[1], a[2] * b[2])


@njit(cache=True, inline="always")
def scale3(a, s):
    """a * s for a scalar s."""
    return (a[0] * s, a[1] * s, a[2] * s)


@njit(cache=True, inline="always")
def div3(a, s):
    """a / s for a scalar s."""
    return (a[0] / s, a[1] / s, a[2] / s)


@njit(cache=True, inline="always")
def max3(a):
    """Largest component."""
    return max(a[0], max(a[1], a[2]))


@njit(cache=True, inline="always")
def madd3(a, b, s):
    """a + b * s: a point along a ray (a origin, b direction, s distance)."""
    return (a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2])


@njit(cache=True, inline="always")
def exp_neg3(k, s):
    """exp(-k s) per component of k, for a scalar s (a transmittance per channel)."""
    return (math.exp(-(k[0] * s)), math.exp(-(k[1] * s)), math.exp(-(k[2] * s)))


@njit(cache=True, inline="always")
def mul_one_minus3(a, k, s):
    """a (1 - k s) per component of a and k, for a scalar s (a ratio-tracking step per
    channel), written a - a (k s) as the kernels' spec_mul_one_minus (spectrum.h) fuses it."""
    return (a[0] - a[0] * (k[0] * s), a[1] - a[1] * (k[1] * s), a[2] - a[2] * (k[2] * s))
