"""Lookup ceiling: raw trilinear density lookups per second on a scene's grid.

No tracking logic and no random-number generator beyond a 32-bit hash. Work item i owns the
camera ray of pixel i clipped to the medium box (pixels whose ray misses the box are left
out) and, in each of ``passes`` passes, looks the grid up at ``n_lookups`` evenly spaced
points with a random offset. That is the memory locality the renderers have (one pixel per
work item, its samples starting along the same ray), so a configuration's lookups per
second over this rate is the fraction of the machine's lookup rate its tracking achieves.
Paths that scatter away read less coherently, so the ceiling is generous.

kernels/bench.cl is the OpenCL twin of ``lookup_sums``; both return per-item sums, so a test
can check they read the same values.
"""

import math
import time

import numpy as np
from numba import njit, prange

from ..reference.grid import grid_lookup

_M = 0xFFFFFFFF


@njit(cache=True, inline="always")
def bench_hash(x):
    s = (x * 747796405 + 2891336453) & _M
    w = (((s >> ((s >> 28) + 4)) ^ s) * 277803737) & _M
    return ((w >> 22) ^ w) & _M


@njit(cache=True, parallel=True)
def lookup_sums(grid, bmin, bmax, segs, n_lookups, passes, seed):
    """Per segment (o, d, t0, t1 as 8 numbers), the sum of passes x n_lookups densities."""
    n = segs.shape[0]
    out = np.empty(n)
    inv = (1.0 / (bmax[0] - bmin[0]), 1.0 / (bmax[1] - bmin[1]), 1.0 / (bmax[2] - bmin[2]))
    b0 = (bmin[0], bmin[1], bmin[2])
    for gid in prange(n):
        s = segs[gid]
        dt = (s[7] - s[6]) / n_lookups
        st = bench_hash(gid ^ bench_hash(seed))
        acc = 0.0
        for _ in range(passes):
            st = bench_hash(st)
            t = s[6] + (st >> 8) * (1.0 / 16777216.0) * dt
            for k in range(n_lookups):
                tk = t + k * dt
                acc += grid_lookup(grid, b0, inv, (s[0] + tk * s[3], s[1] + tk * s[4],
                                                   s[2] + tk * s[5]))
        out[gid] = acc
    return out


def camera_segments(scene):
    """(segments [n, 8] float64 as o, d, t0, t1; bmin; bmax) in the medium's space as the
    renderers use it (the scene frame, or a placed medium's own: reference/medium.to_medium):
    the centre ray of every pixel whose ray crosses the medium box."""
    from ..pack import pack_scene
    from ..scene.loading import require_one_medium
    require_one_medium(scene, "the lookup ceiling (--no-ceiling skips it)")
    from ..reference.camera import camera_ray
    from ..reference.integrator import ray_box
    from ..reference.medium import to_medium, to_medium_dir
    pk = pack_scene(scene)
    prm, med = pk.params[0], pk.medium[0]
    w, h = scene.camera.resolution
    bmin, bmax = np.array(med["bmin"]), np.array(med["bmax"])
    segs = []
    for py in range(h):
        for px in range(w):
            o, d = camera_ray(prm, px, py, 0.5, 0.5, 0.5, 0.5)
            o, d = np.asarray(to_medium(med, o)), np.asarray(to_medium_dir(med, d))
            t0, t1 = ray_box(o, d, bmin, bmax)
            t0 = max(t0, 0.0)
            if t1 > t0:
                segs.append(list(o) + list(d) + [t0, t1])
    return np.array(segs, np.float64).reshape(-1, 8), bmin, bmax


class OpenCLLookups:
    """The lookup kernel built for one device, bound to one grid and its segments."""

    def __init__(self, grid, bmin, bmax, segs, device=None, local_size=1, lanes=None):
        from ..cl.context import cl_context
        from ..cl.lanes import lane_options, resolve_gathers, resolve_lanes
        self.clc = cl_context(device)
        self.lanes = resolve_lanes(lanes, self.clc.device)
        gathers = resolve_gathers(self.clc.device)
        prg, _ = self.clc.program("bench.cl", lane_options(self.lanes, gathers))
        self.kernel = self.clc.kernel(prg, "lookup_throughput")
        g = np.ascontiguousarray(grid, np.float32)
        nz, ny, nx = g.shape
        self.dims = np.array([nx, ny, nz, 0], np.int32)
        self.bmin = np.array(list(bmin) + [0.0], np.float32)
        self.bmax = np.array(list(bmax) + [0.0], np.float32)
        self.grid_buf = self.clc.to_device(g)
        self.n = len(segs)
        self.seg_buf = self.clc.to_device(segs, np.float32)
        self.out, self.out_buf = self.clc.output(self.n)
        self.local_size = local_size

    def sums(self, n_lookups, passes, seed):
        items = -(-self.n // self.lanes)
        self.clc.run(self.kernel, items, self.local_size, self.grid_buf, self.dims, self.bmin,
                     self.bmax, self.seg_buf, np.uint32(n_lookups), np.uint32(passes),
                     np.uint32(seed), self.out_buf, np.int32(self.n),
                     outs=[(self.out, self.out_buf)])
        return self.out.copy()


def lookup_ceiling(scene, backends=("opencl", "numba"), lookups_per_backend=1 << 24,
                   n_lookups=64, repeats=3, device=None, lanes=None):
    """{backend: lookups per second}: median of ``repeats`` timed launches of about
    ``lookups_per_backend`` lookups each (first launch, with compilation, not timed). OpenCL
    is timed at work-group size 1 (the renderer's) and at the driver's choice; the faster
    counts, as a ceiling should. OpenCL's lookups run at lane width ``lanes`` (None: the
    renderer's default), so a render's fraction of the ceiling compares like with like."""
    segs, bmin, bmax = camera_segments(scene)
    if len(segs) == 0:
        return {}
    passes = max(1, math.ceil(lookups_per_backend / (len(segs) * n_lookups)))
    total = len(segs) * n_lookups * passes
    runners = {}
    if "opencl" in backends:
        for ls in (1, None):
            r = OpenCLLookups(scene.grid, bmin, bmax, segs, device, local_size=ls, lanes=lanes)
            runners[("opencl", ls)] = lambda seed, r=r: r.sums(n_lookups, passes, seed)
    if "numba" in backends:
        g64 = np.ascontiguousarray(scene.grid, np.float64)
        runners[("numba", 0)] = lambda seed: lookup_sums(g64, bmin, bmax, segs, n_lookups,
                                                         passes, seed)
    for run in runners.values():
        run(0)
    times = {k: [] for k in runners}
    for rep in range(repeats):  # alternate so drift hits every runner alike
        for k, run in runners.items():
            t = time.perf_counter()
            run(rep + 1)
            times[k].append(time.perf_counter() - t)
    out = {}
    for (name, _), ts in times.items():
        out[name] = max(out.get(name, 0.0), total / float(np.median(ts)))
    return out
