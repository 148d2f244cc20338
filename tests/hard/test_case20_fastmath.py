"""robustness case 20: with and without -cl-fast-relaxed-math (OpenCL) and fastmath=True (Numba),
the NaN/Inf guard still drops and counts bad samples.

Finite-math-only lets a compiler assume no NaN or Inf exists and fold isnan/isinf/isfinite to
constants; Numba's fastmath=True does fold math.isfinite (a float64 NaN then passes a naive
guard). Guard "sample filter" (kernels/guards.h, volmc/reference/guards.py) therefore tests
the exponent bits as an integer, which no fast-math flag touches. Production builds still use
no fast-math flag (volmc/cl/build.py); volmc/bench/fastmath.py measures what that costs.
"""

import math

import numpy as np
import pytest
from numba import njit

from volmc.bench.fastmath import FAST_MATH
from volmc.backends.opencl import OpenCLBackend
from volmc.backends.numba import NumbaBackend
from volmc.reference.guards import sample_ok
from volmc.reference.integrator import render_pixel
from volmc.render import render
from volmc.scene import scene_from_dict

# 1e39: infinite in the kernels' float32, so the float64 reference drops it too (kept, it
# made the float32 EXR infinite: a point light of intensity 3e38, found by an outside test)
BAD = [math.nan, math.inf, -math.inf, -1.0, -1e-30, 1e39]
GOOD = [0.0, -0.0, 1e-45, 1e-30, 1.0, 3e38]
VALUES = BAD + GOOD

_SOURCE = """
#include "params.h"
#include "lane_io.h"
#include "guards.h"
kernel void t_sample_ok(global const float *c, int signed_samples, global int *out, int n) {
    lmask on;
    lint i = lane_element(n, &on);
    lmask ok = sample_ok(load_float3(c, i, 3, 0), signed_samples);
    store_uint((global uint *)out, i, 1, 0, as_luint(ok & 1), on);
}
"""


def _expected(c, signed):
    finite = all(math.isfinite(x) and abs(x) <= float(np.finfo(np.float32).max) for x in c)
    return finite and (signed or all(x >= 0.0 for x in c))


def _samples():
    """Every bad or good value in each of the three channels, the others 1.0."""
    rows = []
    for v in VALUES:
        for k in range(3):
            c = [1.0, 1.0, 1.0]
            c[k] = v
            rows.append(c)
    return rows


@pytest.mark.parametrize("options", [(), (FAST_MATH,)], ids=["default", "fast-relaxed-math"])
def test_case20_opencl_guard_survives_fast_math(options, lanes):
    """robustness case 20, OpenCL: sample_ok (kernels/guards.h) built with and without
    -cl-fast-relaxed-math rejects NaN, +-Inf and negative channels (unless signed) and keeps
    zeros, -0.0, subnormals and the largest finite values; then whole renders with NaN, +Inf
    and negative environment radiance drop and count every sample (image 0, finite), and a
    normal render (white furnace) still equals L."""
    from cl_harness import build_source, out_buf, run_kernel, to_dev
    prg = build_source("t_guard.cl", _SOURCE, options)
    rows = _samples()
    with np.errstate(over="ignore"):   # 1e39 is meant to become inf
        c = np.array(rows, np.float32)
    cb = to_dev(c.ravel())
    out, ob = out_buf(len(rows), np.int32)
    for signed in (0, 1):
        run_kernel(prg, "t_sample_ok", len(rows), cb, np.int32(signed), ob, outs=[(out, ob)])
        want = [_expected([float(x) for x in r], signed) for r in c]
        assert [bool(x) for x in out] == want, (signed, list(zip(c.tolist(), out, want)))

    for env in ([math.nan] * 3, [math.inf, 1.0, 1.0], [1.0, -1.0, 1.0]):
        scene = scene_from_dict(_furnace())
        be = OpenCLBackend(scene, options=options, lanes=lanes)
        be.params[0]["env"] = env
        res = render(scene, backend=be, progress=False)
        n = res.film.spp * 16
        assert res.counters["dropped"] == n, (env, res.counters)
        assert np.all(res.film.mean() == 0.0)
    scene = scene_from_dict(_furnace(spp=128))
    res = render(scene, backend=OpenCLBackend(scene, options=options, lanes=lanes),
                 progress=False)
    _check_furnace(res)


def _furnace(spp=8):
    return {"camera": {"eye": [0, 0, 4], "target": [0, 0, 0], "fov": 40, "resolution": [4, 4]},
            "medium": {"bounds": [[-1, -1, -1], [1, 1, 1]], "density": 1.0, "scale": 2.0,
                       "albedo": 1.0, "phase": {"type": "hg", "g": 0.5}},
            "lights": [{"type": "environment", "radiance": 0.5}],
            "render": {"spp": spp, "max_depth": -1}}


def _check_furnace(res):
    from stats import ALPHA, z_bound
    m = res.film.mean()
    se = np.sqrt(res.film.variance_of_mean())
    assert res.counters["dropped"] == 0
    assert np.abs((m - 0.5) / se).max() < z_bound(ALPHA, m.size)


def test_case20_numba_guard_survives_fastmath():
    """robustness case 20, Numba: the reference guard compiled with fastmath=True (directly, and
    inlined into a fastmath=True render_pixel, the function that applies it) drops and counts
    NaN, +Inf and negative samples exactly like the normal build; the fastmath render of a
    white furnace still equals L."""
    fm_ok = njit(fastmath=True)(sample_ok.py_func)
    for r in _samples():
        for signed in (0, 1):
            assert fm_ok(r[0], r[1], r[2], signed) == _expected(r, signed), (r, signed)
            assert sample_ok(r[0], r[1], r[2], signed) == _expected(r, signed), (r, signed)

    fm_pixel = njit(fastmath=True)(render_pixel.py_func)

    def run(be, spp):
        w, h = be.scene.camera.resolution
        s = np.zeros((h, w, 4))   # RGBA sums, as the film keeps them
        q = np.zeros((h, w, 4))
        cnt = np.zeros((w * h, be.counters.shape[1]), np.int64)
        for pix in range(w * h):
            pk = be.packed
            fm_pixel(pk.params, pk.lights, pk.env, be.media, be.rec[0], pix, 0, spp, s, q, cnt[pix])
        return s[..., :3] / spp, q[..., :3], cnt.sum(axis=0)

    from volmc.params import C_DROPPED
    for env in ([math.nan] * 3, [math.inf, 1.0, 1.0], [1.0, -1.0, 1.0]):
        be = NumbaBackend(scene_from_dict(_furnace()))
        be.packed.params[0]["env"] = env
        mean, _, cnt = run(be, 8)
        assert cnt[C_DROPPED] == 8 * 16, (env, cnt)
        assert np.all(mean == 0.0)
    be = NumbaBackend(scene_from_dict(_furnace()))
    spp = 128
    mean, sq, cnt = run(be, spp)
    var = (sq / spp - mean ** 2) / (spp - 1)
    from stats import ALPHA, z_bound
    assert cnt[C_DROPPED] == 0
    assert np.abs((mean - 0.5) / np.sqrt(var)).max() < z_bound(ALPHA, mean.size)
