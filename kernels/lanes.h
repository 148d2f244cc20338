/* Lane types: one kernel source for every lane width W = LANES (1, 4, 8 or 16; build option
 * -DLANES=W, volmc/cl/lanes.py). A work-item traces W paths in lock-step, the SPMD-on-SIMD
 * model of ispc: every per-path value is a lane type (W floats in one OpenCL vector), control
 * flow that depends on a path narrows a lane mask instead of branching, and a loop runs while
 * ANY lane still needs it. Data every lane shares (the parameter record, the medium, the
 * lights, constants) stays scalar. The width lives here and nowhere else; algorithm code
 * reads like the scalar code it was, with the helpers below where an operator would not
 * do.
 *
 * W = 1 is plain scalar code (what GPUs want), not a vector of one: OpenCL gives 1 for a
 * true scalar comparison but -1 (all bits) for a true vector one, any()/all() test the top
 * bit, and select() tests the top bit of a vector mask but "!= 0" of a scalar one. So masks
 * are combined only with &, |, && , || and ! (correct at every width: ~ is not, since ~1 is
 * true), and tested only through ANY and ALL. select() is used as it is: it is right for
 * both kinds of mask.
 *
 * Positions, directions and RGB are structures of arrays (lvec3: x, y and z of W lanes);
 * their helpers have the names of the reference's tuple helpers (volmc/reference/vec.py:
 * add3, mul3, scale3, madd3, ...). A gather (one address per lane) is a loop over lanes,
 * which the compiler unrolls: the hardware has no faster way on most CPUs, and a lane
 * whose path is not active must still hold a valid address (callers select one). */
#ifndef VOLMC_LANES_H
#define VOLMC_LANES_H

/* A CPU without AVX-512 passes 512-bit vectors (the counters' ulong8 at W = 8, every lane
 * type at W = 16) to PoCL's out-of-line built-ins in memory, and clang says so once per
 * call ("changes the ABI"): about 20 warnings per build, and a pyopencl CompilerWarning,
 * for code that is correct. PoCL refuses -Wno-psabi as a build option; the pragma is
 * clang's own, so other compilers skip it. */
#ifdef __clang__
#pragma clang diagnostic ignored "-Wpsabi"
#endif

#ifndef LANES
#define LANES 1
#endif

#if LANES == 1
typedef float lfloat;
typedef int lint;
typedef uint luint;
typedef ulong lulong;
typedef int lmask; /* 1 true, 0 false */
#define ANY(m) ((m) != 0)
#define ALL(m) ((m) != 0)
#define LANES_ALL 1
#define LANE_IOTA 0
#define to_lfloat(x) convert_float(x)
#define to_lint(x) convert_int(x)
#define to_lint_rtz(x) convert_int_rtz(x)
#define to_luint(x) convert_uint(x)
#define to_lulong(x) convert_ulong(x)
#define as_lfloat(x) as_float(x)
#define as_luint(x) as_uint(x)
#define as_lint(x) as_int(x)
#elif LANES == 4 || LANES == 8 || LANES == 16
#define LANE_CAT_(a, b) a##b
#define LANE_CAT(a, b) LANE_CAT_(a, b)
#define LANE_TYPE(t) LANE_CAT(t, LANES)
typedef LANE_TYPE(float) lfloat;
typedef LANE_TYPE(int) lint;
typedef LANE_TYPE(uint) luint;
typedef LANE_TYPE(ulong) lulong;
typedef LANE_TYPE(int) lmask; /* -1 true, 0 false, as vector comparisons give */
#define ANY(m) any(m)
#define ALL(m) all(m)
#define LANES_ALL ((lmask)(-1))
#define to_lfloat(x) LANE_CAT(convert_, LANE_TYPE(float))(x)
#define to_lint(x) LANE_CAT(convert_, LANE_TYPE(int))(x)
#define to_lint_rtz(x) LANE_CAT(LANE_CAT(convert_, LANE_TYPE(int)), _rtz)(x)
#define to_luint(x) LANE_CAT(convert_, LANE_TYPE(uint))(x)
#define to_lulong(x) LANE_CAT(convert_, LANE_TYPE(ulong))(x)
#define as_lfloat(x) LANE_CAT(as_, LANE_TYPE(float))(x)
#define as_luint(x) LANE_CAT(as_, LANE_TYPE(uint))(x)
#define as_lint(x) LANE_CAT(as_, LANE_TYPE(int))(x)
#if LANES == 4
#define LANE_IOTA ((lint)(0, 1, 2, 3))
#elif LANES == 8
#define LANE_IOTA ((lint)(0, 1, 2, 3, 4, 5, 6, 7))
#else
#define LANE_IOTA ((lint)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#endif
#else
#error "LANES must be 1, 4, 8 or 16"
#endif

/* Loops over the three axes: unrolled at W > 1, where the per-axis arrays of lane values
 * then stay in vector registers (5-10 % faster at W = 16 on the default cloud); not at
 * W = 1, where unrolling them made PoCL's code twice as slow (0.26 against 0.53 M
 * samples/s). */
#if LANES == 1
#define LANE_UNROLL
#else
#define LANE_UNROLL _Pragma("unroll")
#endif

/* Records of lane values (a walk, a path, a segment) start zeroed, `Walk wk = {0}`, never
 * uninitialised: a lane that no code has written yet is otherwise undefined to LLVM, a mask
 * that combines it is undefined too, and ANY() of it is a branch on an undefined value,
 * which the optimiser may assume never happens. It did: with both majorant kinds compiled
 * in, estimate_batch at W > 1 under the octree returned T = 1 without a lookup (correct
 * with -cl-opt-disable, and once the walk record was zeroed). Zeroing a record costs
 * a few stores per walk or per work-item. */

/* A mask of every lane or none from a condition every lane shares. (A cast would not do:
 * (lmask)(1) is 1 in every lane, which vector masks read as false.) */
static inline lmask lanes_if(int c) { return c ? LANES_ALL : (lmask)(0); }

/* Lane l of a lane value, and lane l set, through a union (the compiler keeps the vector in
 * registers once the lane loop is unrolled). */
typedef union {
    lfloat v;
    float a[LANES];
} LaneFloats;
typedef union {
    lint v;
    int a[LANES];
} LaneInts;
typedef union {
    luint v;
    uint a[LANES];
} LaneUints;
typedef union {
    lulong v;
    ulong a[LANES];
} LaneUlongs;

static inline int lane_on(lmask m, int l) {
    LaneInts u;
    u.v = m;
    return u.a[l] != 0;
}

static inline float lane_float(lfloat v, int l) {
    LaneFloats u;
    u.v = v;
    return u.a[l];
}

static inline int lane_int(lint v, int l) {
    LaneInts u;
    u.v = v;
    return u.a[l];
}

static inline uint lane_uint(luint v, int l) {
    LaneUints u;
    u.v = v;
    return u.a[l];
}

/* Sum of the lanes. */
static inline ulong lane_sum_ulong(lulong v) {
    LaneUlongs u;
    u.v = v;
    ulong s = 0;
    for (int l = 0; l < LANES; ++l) s += u.a[l];
    return s;
}

/* The number of lanes of m. */
static inline int lane_count(lmask m) {
#if LANES == 1
    return m != 0;
#else
    LaneInts u;
    u.v = m & 1;
    int n = 0;
    for (int l = 0; l < LANES; ++l) n += u.a[l];
    return n;
#endif
}

/* Active lanes: 1 per lane of m (to add to a per-lane counter). */
static inline lulong lane_ones(lmask m) { return to_lulong(m & 1); }

/* The bitwise or of v over the lanes of m: a set every lane shares, so that code can branch
 * on it once instead of testing a lane mask per bit (halving the vector each step). */
static inline int lane_or(lint v, lmask m) {
    v = select((lint)(0), v, m);
#if LANES == 1
    return v;
#else
#if LANES == 16
    int8 v8 = v.lo | v.hi;
#elif LANES == 8
    int8 v8 = v;
#endif
#if LANES >= 8
    int4 v4 = v8.lo | v8.hi;
#else
    int4 v4 = v;
#endif
    int2 v2 = v4.lo | v4.hi;
    return v2.x | v2.y;
#endif
}

/* Gathers load lane by lane. LLVM turns that loop into a vector gather instruction, which
 * on AMD's Zen 5 is slower than scalar loads and on Intel's AVX-512 Xeons faster:
 * -DGATHER_SCALAR=1 keeps the loads scalar with volatile, 0 lets LLVM gather. The host
 * chooses per device (volmc.cl.lanes.device_gathers, measured in docs/lanes.md); the loaded
 * values are the same either way. */
#ifndef GATHER_SCALAR
#define GATHER_SCALAR 0
#endif
#if GATHER_SCALAR
#define GATHER_PTR(T, p) ((volatile global const T *)(p))
#else
#define GATHER_PTR(T, p) (p)
#endif

/* base[i] in each lane. */
static inline lfloat gather_float(global const float *base, lint i) {
#if LANES == 1
    return base[i];
#else
    LaneInts k;
    LaneFloats r;
    k.v = i;
#pragma unroll
    for (int l = 0; l < LANES; ++l) r.a[l] = GATHER_PTR(float, base)[k.a[l]];
    return r.v;
#endif
}

static inline lint gather_int(global const int *base, lint i) {
#if LANES == 1
    return base[i];
#else
    LaneInts k, r;
    k.v = i;
#pragma unroll
    for (int l = 0; l < LANES; ++l) r.a[l] = GATHER_PTR(int, base)[k.a[l]];
    return r.v;
#endif
}

/* base[(slot << 9) | within] in each lane: brick pools may exceed 2^31 voxels. */
static inline lfloat gather_float_brick(global const float *base, lint slot, lint within) {
#if LANES == 1
    return base[((size_t)slot << 9) | (size_t)within];
#else
    LaneInts s, w;
    LaneFloats r;
    s.v = slot;
    w.v = within;
#pragma unroll
    for (int l = 0; l < LANES; ++l)
        r.a[l] = GATHER_PTR(float, base)[((size_t)s.a[l] << 9) | (size_t)w.a[l]];
    return r.v;
#endif
}

/* Three ints per lane (a cell). */
typedef struct {
    lint x, y, z;
} lint3;

/* Two floats per lane (a pair of uniforms). */
typedef struct {
    lfloat x, y;
} lvec2;

/* Structures of arrays: a point, a direction or an RGB value per lane. */
typedef struct {
    lfloat x, y, z;
} lvec3;

static inline lvec3 v3(lfloat x, lfloat y, lfloat z) {
    lvec3 r = {x, y, z};
    return r;
}

/* The same value in every lane. */
static inline lvec3 v3u(float3 a) { return v3((lfloat)(a.x), (lfloat)(a.y), (lfloat)(a.z)); }

static inline lvec3 v3s(lfloat s) { return v3(s, s, s); }

static inline lvec3 add3(lvec3 a, lvec3 b) { return v3(a.x + b.x, a.y + b.y, a.z + b.z); }

static inline lvec3 sub3(lvec3 a, lvec3 b) { return v3(a.x - b.x, a.y - b.y, a.z - b.z); }

static inline lvec3 mul3(lvec3 a, lvec3 b) { return v3(a.x * b.x, a.y * b.y, a.z * b.z); }

static inline lvec3 scale3(lvec3 a, lfloat s) { return v3(a.x * s, a.y * s, a.z * s); }

static inline lvec3 div3(lvec3 a, lfloat s) { return v3(a.x / s, a.y / s, a.z / s); }

static inline lfloat max3(lvec3 a) { return fmax(a.x, fmax(a.y, a.z)); }

/* a + b s: a point along a ray (a origin, b direction, s distance). */
static inline lvec3 madd3(lvec3 a, lvec3 b, lfloat s) {
    return v3(a.x + s * b.x, a.y + s * b.y, a.z + s * b.z);
}

static inline lfloat dot3(lvec3 a, lvec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

static inline lvec3 neg3(lvec3 a) { return v3(-a.x, -a.y, -a.z); }

/* b where m, else a (select's order). */
static inline lvec3 sel3(lvec3 a, lvec3 b, lmask m) {
    return v3(select(a.x, b.x, m), select(a.y, b.y, m), select(a.z, b.z, m));
}

/* Lane l of a, as a float3 (scalar code that handles one lane: records, outputs). */
static inline float3 lane_vec3(lvec3 a, int l) {
    return (float3)(lane_float(a.x, l), lane_float(a.y, l), lane_float(a.z, l));
}

#endif
