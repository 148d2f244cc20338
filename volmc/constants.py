"""Every constant the kernels share with Python, defined once.

The OpenCL kernels never define these themselves: ``volmc/cl/structs.py`` writes each
public upper-case name of this module into the generated header ``params.h`` (an ``int``
as a decimal literal, a ``U32`` as an unsigned hexadecimal literal, a ``float`` as a
float literal), and the Numba reference imports them from here. ``tests/test_constants.py``
fails if a kernel sees a different value than the reference, or if a kernel source file
``#define``s one of these names by hand.

Constants that only one side needs (for example the C guard ``NO_LIMIT``, which is
``FLT_MAX`` in the kernels and ``math.inf`` in Python) are not listed here.
"""

import math


class U32(int):
    """An unsigned 32-bit constant: written into the kernels' header as ``0x...u``."""

    def __new__(cls, value):
        if not 0 <= value < 2**32:
            raise ValueError(f"{value} is not a 32-bit unsigned value")
        return super().__new__(cls, value)


# --- Mathematics -----------------------------------------------------------------------------

#: 1 / (4 pi): the isotropic phase function and the uniform-sphere pdf, per steradian.
INV_4PI = 1.0 / (4.0 * math.pi)
#: 1 / pi: the uniform pdf on the unit disc, per unit area.
INV_PI = 1.0 / math.pi
#: pi / 2 and pi / 4: the wedge angles of the concentric disc mapping.
PI_OVER_2 = 0.5 * math.pi
PI_OVER_4 = 0.25 * math.pi
#: pi: the panoramic camera's span of latitude.
PI = math.pi
#: 2 pi: a full turn in radians.
TWO_PI = 2.0 * math.pi

# --- Random numbers (volmc/reference/rng.py has the convention) ------------------------------

#: Philox4x32 round multipliers (Salmon, Moraes, Dror, Shaw 2011).
PHILOX_M0 = U32(0xD2511F53)
PHILOX_M1 = U32(0xCD9E8D57)
#: Philox4x32 key increments per round (the golden ratio and sqrt(3) - 1, as 32-bit fractions).
PHILOX_W0 = U32(0x9E3779B9)
PHILOX_W1 = U32(0xBB67AE85)
#: Philox rounds: 10 is Random123's recommendation (passes BigCrush with margin).
PHILOX_ROUNDS = 10
#: 2^-24, one step of the 24-bit uniform grid: uniforms are (word >> 8) * UNIFORM_SCALE.
UNIFORM_SCALE = 1.0 / 16777216.0

#: Random-number streams of one sample: the path's decisions (camera jitter, free flight,
#: phase, roulette, environment sampling) ...
STREAM_PATH = 0
#: ... the transmittance estimates of shadow rays ...
STREAM_SHADOW = 1
#: ... and tests and benchmarks that drive a single technique.
STREAM_TEST = 2

# --- Free flight ---------------------------------------------------------------------------

#: Free-flight outcomes: the walk passed the end of its segment without a real collision ...
EVENT_ESCAPE = 0
#: ... a real collision (the path scatters there) ...
EVENT_SCATTER = 1
#: ... or the step cap ended the walk (counted; the caller ends the path).
EVENT_CAPPED = 2

# --- Media (volmc/reference/medium.py) ------------------------------------------------------

#: Where a medium's density comes from: one value everywhere (a homogeneous medium) ...
DENSITY_CONSTANT = 0
#: ... a voxel grid, trilinear between voxel centres ...
DENSITY_GRID = 1
#: ... or a 1-D test profile of x alone (tests and the estimator benchmark).
DENSITY_RAMP = 2
DENSITY_GAUSS_BUMP = 3
DENSITY_GAUSS_HOLE = 4
DENSITY_COSINE = 5
#: ... or a voxel grid stored as 8^3 bricks behind an index table (sparse_grid.py): the same
#: trilinear values as DENSITY_GRID, in memory that scales with the non-empty bricks.
DENSITY_BRICKS = 6

#: The majorant structure: one segment with the medium's global bounds ...
MAJORANT_GLOBAL = 0
#: ... or a coarse grid of per-cell bounds, walked cell by cell with a 3-D DDA ...
MAJORANT_GRID = 1
#: ... or an octree of per-node bounds, split where the bounds are loose (octree.py), whose
#: leaves are walked in order along the ray.
MAJORANT_OCTREE = 2
#: Octree depth at most: the finest leaves are 2^OCTREE_MAX_DEPTH cells per axis.
OCTREE_MAX_DEPTH = 7

#: How extinction depends on colour: grey (one extinction for all three channels) ...
SPECTRAL_GREY = 0
#: ... or per channel (medium.scale = [r, g, b]) with free flight by spectral tracking
#: (Kutz et al. 2017): one majorant for every channel, collision probabilities from the
#: channels' weighted coefficients ...
SPECTRAL_TRACKING = 1
#: ... or the same with one channel picked at random per path (render.spectral = "channel"):
#: the baseline the others are measured against ...
SPECTRAL_CHANNEL = 2
#: ... or hero-channel spectral MIS (Miller et al. 2019; pbrt-v4): a random hero channel's
#: delta tracking decides, every channel is weighted by the balance heuristic over the three
#: channels' decision probabilities (render.spectral = "hero").
SPECTRAL_HERO = 3

#: Emission (medium.emission): none ...
EMISSION_NONE = 0
#: ... radiance x field(x) ...
EMISSION_RADIANCE = 1
#: ... or blackbody radiance of temperature(x), through a table in kelvin (medium.py).
EMISSION_TEMPERATURE = 2
#: Entries of the blackbody table over [0, the hottest temperature of the scene] kelvin:
#: linear interpolation between them is within 0.01 % of the conversion (relative to the
#: brightest channel) from 1000 K up for a 2000 K table, 0.2 % for a 20000 K one
#: (tests/test_media.py).
BLACKBODY_TABLE_SIZE = 4096

#: How emission reaches a scattering vertex (render.emission_sampling; volmc/emitters.py):
#: only where a flight's tentative collisions land (the collision estimator) ...
EMISSION_SAMPLING_COLLISION = 0
#: ... by next-event estimation towards points sampled in the emitting media, flights after a
#: scattering vertex gathering none ...
EMISSION_SAMPLING_LIGHT = 1
#: ... or both, weighed by render.mis (docs/emission_sampling.md).
EMISSION_SAMPLING_MIS = 2
#: Cells per axis at most of an emitting medium's sampling distribution.
EMITTER_MAX_CELLS = 64
#: A lookup is counted as over its segment's majorant (C_OVER_MAJORANT) when it exceeds it
#: by more than this fraction. In float32 an extinction that equals its majorant -- a
#: constant grid's interpolation, overlapping media's sum -- may round an ulp or two above
#: it (a differential fuzz of the kernels against the reference counted 2 of 146,858
#: lookups on two overlapping constant media, a bias of 2e-6 at most, and the render warned
#: that its image was biased). 2^-20 is 16 float32 ulps; a majorant that is wrong is off by
#: far more.
OVER_MAJORANT_SLACK = 2.0 ** -20

# --- Tracking (volmc/reference/tracking.py) ----------------------------------------------------

#: What the one tracking loop does at a tentative collision: free flight (a real collision
#: ends the walk, the path scatters there) ...
TRACK_FREE_FLIGHT = 0
#: ... track-length transmittance (a real collision ends the walk with T = 0) ...
TRACK_LENGTH = 1
#: ... ratio tracking (T *= 1 - mu / sigma_maj) ...
TRACK_RATIO = 2
#: ... residual ratio tracking with the segment's minorant as control ...
TRACK_RESIDUAL_RATIO = 3
#: ... next-flight ratio tracking (each vertex adds the chance the next flight escapes) ...
TRACK_NEXT_FLIGHT = 4
#: ... or, per segment, the technique ``auto_segment_technique`` picks (render.transmittance =
#: "auto"): residual ratio tracking on optically thin segments, track length on the rest.
TRACK_AUTO = 5
#: auto's threshold: a segment whose majorant-minorant gap (sigma_maj - sigma_min) L is at
#: most this many mean free paths gets residual ratio tracking, a thicker one track length
#: (measured: volmc/reference/tracking.py, auto_segment_technique).
AUTO_THIN_DEPTH = 0.1

#: Per-segment transmittance estimators, run on each majorant segment in turn: exp(-sigma L)
#: (exact only on homogeneous segments) ...
SEGMENT_ANALYTIC = 0
#: ... biased ray marching ...
SEGMENT_BIASED_RAYMARCH = 1
#: ... the p-series CMF power series ...
SEGMENT_POWER_SERIES = 2
#: ... unbiased ray marching ...
SEGMENT_UNBIASED_RAYMARCH = 3
#: ... the telescoping (debiased) ray-marching estimator ...
SEGMENT_TELESCOPING = 4
#: ... and jackknife ray marching.
SEGMENT_JACKKNIFE = 5
#: Transmittance-estimator ids: the reference dispatches on them (estimators.transmittance);
#: volmc/techniques.py gives each its name and properties.
ESTIMATOR_ANALYTIC = 0
ESTIMATOR_TRACK_LENGTH = 1
ESTIMATOR_RATIO = 2
ESTIMATOR_RESIDUAL_RATIO = 3
ESTIMATOR_NEXT_FLIGHT = 4
ESTIMATOR_BIASED_RAYMARCH = 5
ESTIMATOR_POWER_SERIES = 6
ESTIMATOR_UNBIASED_RAYMARCH = 7
ESTIMATOR_TELESCOPING = 8
ESTIMATOR_JACKKNIFE = 9
#: render.transmittance = "auto": where the transmittance is the whole estimate ...
ESTIMATOR_AUTO = 10
#: ... and on the shadow rays of scattering paths.
ESTIMATOR_AUTO_SHADOW = 11
#: Biased ray marching's comb: points per majorant mean free path (ceil(this x sigma_maj L)).
RAYMARCH_SAMPLES_PER_MFP = 1.0
#: The most points a comb asks for before an estimator's max_steps cap (comb_count in
#: medium.py): the largest float32 below 2^31, so the kernels' float-to-int conversion stays
#: defined.
COMB_COUNT_LIMIT = 2147483520.0

# --- Multiple importance sampling (volmc/reference/sampling.py) ------------------------------

#: How two sampling strategies are combined (render.mis): the balance heuristic ...
MIS_BALANCE = 0
#: ... or the power heuristic with exponent 2 (Veach 1997).
MIS_POWER = 1

# --- Environment maps (volmc/reference/environment.py) ----------------------------------------

#: How next-event estimation draws environment directions (render.env_sampling): from the
#: map's own density ...
ENV_SAMPLING_IMPORTANCE = 0
#: ... or uniformly over the sphere (to measure what importance sampling gains).
ENV_SAMPLING_UNIFORM = 1

# --- Where a path's samples come from (render.sampler; integrator.py "Samplers") -------------

#: Sample pairs of a path: pair 0 jitters the pixel position, pair 1's x picks the hero
#: channel; then every bounce b < SAMPLER_BOUNCES (b = 0: the camera segment; b: the segment
#: leaving scattering vertex b) owns SAMPLER_PAIRS_PER_BOUNCE pairs from
#: SAMPLER_FIRST_BOUNCE + b * SAMPLER_PAIRS_PER_BOUNCE on, at these offsets:
SAMPLER_PAIR_PIXEL = 0
SAMPLER_PAIR_CHANNEL = 1
SAMPLER_FIRST_BOUNCE = 2
SAMPLER_PAIRS_PER_BOUNCE = 4
#: x: the first uniform of the segment's free flight; y: Russian roulette at its end vertex.
SAMPLER_FLIGHT = 0
#: x: equiangular sampling's distance, one point of the pattern per point light.
SAMPLER_EQUIANGULAR = 1
#: The environment direction of next-event estimation, one point per light sample.
SAMPLER_LIGHT = 2
#: The phase-sampled direction leaving the end vertex.
SAMPLER_PHASE = 3
#: Bounces that take low-discrepancy samples; deeper ones use the counter RNG.
SAMPLER_BOUNCES = 16
#: The thin lens's point on the aperture (camera.aperture > 0 only): the pair after every
#: bounce's, so that adding it moved no other pair, and a pinhole draws nothing for it.
SAMPLER_PAIR_LENS = SAMPLER_FIRST_BOUNCE + SAMPLER_BOUNCES * SAMPLER_PAIRS_PER_BOUNCE

#: Most media in a scene (``[[media]]``), and so most media overlapping at one point: the
#: kernels keep a majorant walk per medium (kernels/medium.h), unrolled at compile time; the
#: Numba reference takes every scene of several media as MAX_MEDIA slots (medium.media_data).
MAX_MEDIA = 8

# --- Phase functions, cameras, lights ---------------------------------------------------------

PHASE_ISOTROPIC = 0
PHASE_HG = 1

#: Camera projections (camera.type; volmc/reference/camera.py): a pinhole or thin lens ...
CAMERA_PERSPECTIVE = 0
#: ... parallel rays from an image plane (a thin lens focuses them too) ...
CAMERA_ORTHOGRAPHIC = 1
#: ... or equirectangular, 360 x 180 degrees around the eye (panoramic_direction).
CAMERA_PANORAMIC = 2

#: Light types (the light array; volmc/reference/lights.py): parallel light or a sun disc ...
LIGHT_DIRECTIONAL = 0
#: ... an isotropic point ...
LIGHT_POINT = 1
#: ... a point shining into a cone ...
LIGHT_SPOT = 2
#: ... or an emitting, opaque sphere.
LIGHT_SPHERE = 3

#: How a path treats point and spot lights (render.equiangular; equiangular_mode in
#: reference/integrator.py): next-event estimation only ...
EQUIANGULAR_OFF = 0
#: ... equiangular sampling alone (its pdf cannot be weighed against free flight's in a
#: varying medium: free flight's density there involves the unknown transmittance) ...
EQUIANGULAR_ALONE = 1
#: ... or both, combined by MIS (homogeneous grey media, where free flight's density
#: sigma e^{-sigma t} is known).
EQUIANGULAR_MIS = 2
#: Equiangular sampling's narrowest interval of angles, relative to the angles' size
#: (2^-13: 1024 float32 ulps). A narrower one is sampled uniformly: between a handful of
#: representable angles the samples would follow a trapezoidal rule of that many points,
#: not the pdf (an error of order 1 / points^2); an interval this narrow seen from the
#: light is one whose 1 / r^2 varies by about 2^-12 along it, where uniform is as good.
EQUIANGULAR_MIN_WIDTH = 2.0 ** -13

# --- Russian roulette ----------------------------------------------------------------------

#: A path of unbounded depth (max_depth = -1) survives roulette with probability
#: min(max(throughput), RR_MAX_SURVIVAL): the cap ends every path, even at albedo 1 in an
#: unbounded medium (Mitsuba 3's policy). With max_depth >= 0 the depth bound ends paths and
#: the cap is 1: a cap of 0.95 cost the default cloud (albedo 0.99, 64 events) twice the MSE
#: per sample, 1.5x the time to equal error (docs/rendering.md, "Russian roulette").
RR_MAX_SURVIVAL = 0.95
#: Russian-roulette survival rules (render.rr): the throughput's largest channel ...
RR_THROUGHPUT = 0
#: ... or the expected throughput after the next scattering (throughput x albedo).
RR_ALBEDO = 1
#: Guard "transmittance roulette" (docs/robustness.md): below this running |T| a
#: transmittance walk goes on with probability |T| / TR_RR_THRESHOLD.
TR_RR_THRESHOLD = 1e-3

# --- Power-series transmittance (volmc/reference/power_series.py) ----------------------------

#: Unbiased ray marching, aggressive roulette: P(order = 0) (Kettunen et al. 2021, p_Z).
URM_P_ZERO = 0.9
#: Once past order 0, every order up to URM_K is evaluated.
URM_K = 2
#: Beyond URM_K, order k is reached with conditional probability min(1, URM_C / k).
URM_C = 2.0
#: Size of the U-statistics buffer. With the constants above P(order >= 14) < 2^-24, which a
#: 24-bit uniform can never pass, so the order stops at 13 and the cap is never reached.
URM_MAX_ORDER = 16
#: P-series CMF: orders are evaluated deterministically until the Poisson cumulative mass
#: reaches this level (Georgiev et al. 2019; their public code uses 0.99).
CMF_GOAL = 0.99
#: Cubic fit of the p-series CMF estimator's expected lookups at Poisson parameter lam:
#: cbrt((CMF_FIT_0 + lam) (CMF_FIT_1 + lam) (CMF_FIT_2 + lam)) (Kettunen et al. 2021).
CMF_FIT_0 = 0.015
CMF_FIT_1 = 0.65
CMF_FIT_2 = 60.3
#: The fit is evaluated at min(lam, CMF_FIT_MAX_LAMBDA): its cube overflowed float32 from
#: lam ~ 7e12 and its integer int32 from ~ 2e9 (a negative comb size of unbiased ray
#: marching, whose step cap then never fired: pixels of -1e7). A budget of ~2^30 lookups is
#: past any step cap that matters and still an int32.
CMF_FIT_MAX_LAMBDA = 2.0 ** 30
#: The p-series CMF estimator's running sums are kept between 2^-CMF_RESCALE_BITS and
#: 2^CMF_RESCALE_BITS by exact power-of-two rescaling (their partial products grow like
#: e^(lam / e) before exp(-tau_bar) brings them down: past float32 from lam ~ 240 on) ...
CMF_RESCALE_BITS = 64
#: ... these two factors, and the natural log of the first, apply it.
CMF_RESCALE_HI = 2.0 ** CMF_RESCALE_BITS
CMF_RESCALE_LO = 2.0 ** -CMF_RESCALE_BITS
CMF_RESCALE_LN = CMF_RESCALE_BITS * math.log(2.0)


def _urm_mean_order(p_zero, k_det, c):
    """E[order] = sum_{k >= 1} P(order >= k) of the aggressive roulette."""
    q, total, k = 1.0 - p_zero, 0.0, 0
    while q > 1e-300:
        k += 1
        if k > k_det:
            q *= min(1.0, c / k)
        total += q
    return total


#: Expected expansion order of unbiased ray marching (0.31945... for the constants above); each
#: order costs one comb, so an estimate makes M (1 + URM_MEAN_ORDER) lookups on average.
URM_MEAN_ORDER = _urm_mean_order(URM_P_ZERO, URM_K, URM_C)

# --- Bias-corrected ray marching (volmc/reference/debiasing.py) ------------------------------

#: Telescoping estimator: level 0 is a jittered comb of ceil(this x sigma_maj L) points ...
TELESCOPE_SAMPLES_PER_MFP = 1.0
#: ... level k halves the step (n 2^k points, nested), and P(K >= k) = TELESCOPE_CONTINUE^k:
#: between 1/4 (the decay of a level difference's second moment, O(h^2)) and 1/2 (the growth
#: of its cost), so both the variance and the expected cost are finite. 3/8 is exact in
#: binary, so the float32 and float64 roulette thresholds agree up to 3^15 / 8^15.
TELESCOPE_CONTINUE = 0.375
#: Level cap. 0.375^17 < 2^-24, so a 24-bit uniform never passes level 16 and the cap (it
#: would be counted in C_CAPPED) is never reached.
TELESCOPE_MAX_LEVEL = 16
#: Jackknife ray marching: lookups per majorant mean free path over all its combs (so its
#: cost equals biased ray marching's at RAYMARCH_SAMPLES_PER_MFP = 1) ...
JACKKNIFE_SAMPLES_PER_MFP = 1.0
#: ... split into this many independent jittered combs (the jackknife's groups).
JACKKNIFE_GROUPS = 2


def kernel_constants():
    """{name: value} of every constant the kernels' header defines, in definition order."""
    return {k: v for k, v in globals().items()
            if k.isupper() and not k.startswith("_") and type(v) in (int, float, U32)}


# --- Low-discrepancy sampler (volmc/reference/sampler.py) ------------------------------------

#: Sampler kinds: independent uniforms (the integrator's counter RNG; sampler_pair returns the
#: top 24 bits of two Philox words for it) ...
SAMPLER_INDEPENDENT = 0
#: ... correlated multi-jittered stratification of n samples per pixel (any n >= 1) ...
SAMPLER_STRATIFIED = 1
#: ... or Owen-scrambled Sobol points with Burley's shuffled padding (every power-of-two
#: prefix of the samples of a pixel is a (0, m, 2)-net).
SAMPLER_SOBOL = 2
#: The Philox stream of the sampler's per-(pixel, pair, epoch) seeds: counter (pair, pixel,
#: epoch, STREAM_SAMPLER), disjoint from the path's draws (streams 0 to 2 above).
STREAM_SAMPLER = 3


def _frac_u32(x, even=False, odd=False):
    """The first 32 bits of the fractional part of x (a nothing-up-my-sleeve constant), with
    bit 0 cleared (even) or set (odd)."""
    v = int((x % 1.0) * 2**32)
    return U32(v & ~1 if even else v | 1 if odd else v)


#: Largest n of SAMPLER_STRATIFIED (a larger n acts as this one): its m x rows grid then has
#: at most 2^24 cells, so every 1-D stratum still holds a 24-bit uniform.
SAMPLER_MAX_N = 1 << 24
#: Hash-based Owen scrambling (sampler.owen_scramble): the even multipliers of its
#: x ^= x * C steps, the fractional parts of sqrt(23), sqrt(29) and sqrt(31) (bit 0 cleared) ...
OWEN_E0 = _frac_u32(math.sqrt(23.0), even=True)
OWEN_E1 = _frac_u32(math.sqrt(29.0), even=True)
OWEN_E2 = _frac_u32(math.sqrt(31.0), even=True)
#: ... and the odd multiplier that derives its second seed word, from sqrt(37).
OWEN_SEED_MUL = _frac_u32(math.sqrt(37.0), odd=True)
#: Hashes of the stratified sampler (sampler.hash_u32 for the jitter, sampler.permute_index
#: for the permutations): odd multipliers from the fractional parts of sqrt(41) to sqrt(59).
HASH_M0 = _frac_u32(math.sqrt(41.0), odd=True)
HASH_M1 = _frac_u32(math.sqrt(43.0), odd=True)
PERM_M0 = _frac_u32(math.sqrt(47.0), odd=True)
PERM_M1 = _frac_u32(math.sqrt(53.0), odd=True)
PERM_M2 = _frac_u32(math.sqrt(59.0), odd=True)

# --- Segment recording (reference/medium.py: record_segment; volmc/bench/segments.py) --------

#: Floats per row of a pixel's segment record: o(3), d(3), t0, t1, kind, the layout of the
#: estimator runners' rays; row 0 holds the count and the capacity instead.
RECORD_COLUMNS = 9
#: Kinds of a recorded segment: the primary ray's clipped segment ...
RECORD_CAMERA = 0
#: ... or a shadow ray's, as shadow_transmittance hands it to the estimator.
RECORD_SHADOW = 1
