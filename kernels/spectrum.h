/* The type of per-channel weights in the tracking loop (transmittance estimates, spectral
 * tracking's flight weights): `spec` is float3 when the build has colour-dependent
 * extinction (FEATURE_CHROMATIC) and float otherwise, so a grey scene runs the scalar
 * arithmetic it always ran. The reference always carries RGB tuples (volmc/reference/vec.py);
 * for a grey medium its three channels are equal, and the kernels' float is any of them. */
#ifndef VOLMC_SPECTRUM_H
#define VOLMC_SPECTRUM_H

#include "features.h"

#if FEATURE_CHROMATIC
typedef float3 spec;
static inline float spec_max(float3 a) { return fmax(a.x, fmax(a.y, a.z)); }
static inline float3 spec_rgb(float3 a) { return a; }
static inline float spec_first(float3 a) { return a.x; }
#else
typedef float spec;
static inline float spec_max(float a) { return a; }
static inline float3 spec_rgb(float a) { return (float3)(a); }
static inline float spec_first(float a) { return a; }
#endif

#endif
