"""Lookup ceiling: raw trilinear density lookups per second on a scene's grid.

No tracking logic, no random-number generator beyond a 32-bit hash: each work item draws two
points in the box and looks the grid up at ``n_lookups`` evenly spaced points between them
(coherent memory access, as along a tracking ray). kernels/bench.cl is the OpenCL twin of
``lookup_sums`` below; both return the per-item sums, so a test can check they read the same
values. A renderer's lookups per second divided by this ceiling is the fraction of the
machine's lookup rate its tracking achieves.
"""

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


@njit(cache=True, inline="always")
def _uniform(st):
    st = bench_hash(st)
    return st, (st >> 8) * (1.0 / 16777216.0)


@njit(cache=True, parallel=True)
def lookup_sums(grid, bmin, bmax, n_items, n_lookups, seed):
    """Per work item, the sum of n_lookups densities along a random segment in the box."""
    out = np.empty(n_items)
    ext = (bmax[0] - bmin[0], bmax[1] - bmin[1], bmax[2] - bmin[2])
    inv = (1.0 / ext[0], 1.0 / ext[1], 1.0 / ext[2])
    b0 = (bmin[0], bmin[1], bmin[2])
    for gid in prange(n_items):
        st = bench_hash(gid ^ bench_hash(seed))
        u = np.empty(6)
        for j in range(6):
            st, u[j] = _uniform(st)
        a = (b0[0] + ext[0] * u[0], b0[1] + ext[1] * u[1], b0[2] + ext[2] * u[2])
        b = (b0[0] + ext[0] * u[3], b0[1] + ext[1] * u[4], b0[2] + ext[2] * u[5])
        acc = 0.0
        for k in range(n_lookups):
            s = (k + 0.5) / n_lookups
            p = (a[0] + (b[0] - a[0]) * s, a[1] + (b[1] - a[1]) * s, a[2] + (b[2] - a[2]) * s)
            acc += grid_lookup(grid, b0, inv, p)
        out[gid] = acc
    return out


class OpenCLLookups:
    """The lookup kernel built for one device, bound to one grid."""

    def __init__(self, grid, bounds, device=None, local_size=1):
        import pyopencl as cl

        from ..cl.build import assemble, build_program
        from ..cl.device import select_device
        self.cl = cl
        dev = device if device is not None and not isinstance(device, str) \
            else select_device(device)
        self.ctx = cl.Context([dev])
        self.queue = cl.CommandQueue(self.ctx)
        prg, _ = build_program(self.ctx, dev, assemble("bench.cl"), [])
        self.kernel = cl.Kernel(prg, "lookup_throughput")
        g = np.ascontiguousarray(grid, np.float32)
        nz, ny, nx = g.shape
        self.dims = np.array([nx, ny, nz, 0], np.int32)
        self.bmin = np.array(list(bounds[0]) + [0.0], np.float32)
        self.bmax = np.array(list(bounds[1]) + [0.0], np.float32)
        self.grid_buf = cl.Buffer(self.ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                                  hostbuf=g)
        self.local_size = local_size

    def sums(self, n_items, n_lookups, seed):
        out = np.empty(n_items, np.float32)
        buf = self.cl.Buffer(self.ctx, self.cl.mem_flags.WRITE_ONLY, out.nbytes)
        local = None if self.local_size is None else (self.local_size,)
        self.kernel(self.queue, (n_items,), local, self.grid_buf, self.dims, self.bmin,
                    self.bmax, np.uint32(n_lookups), np.uint32(seed), buf)
        self.cl.enqueue_copy(self.queue, out, buf)
        self.queue.finish()
        return out


def lookup_ceiling(scene, backends=("opencl", "numba"), n_items=1 << 16, n_lookups=256,
                   repeats=3, device=None):
    """{backend: lookups per second} (median of ``repeats`` launches, compilation excluded)."""
    grid = scene.grid
    bounds = scene.spec.medium.bounds
    out = {}
    runners = {}
    if "opencl" in backends:
        cl_runner = OpenCLLookups(grid, bounds, device)
        runners["opencl"] = lambda seed: cl_runner.sums(n_items, n_lookups, seed)
    if "numba" in backends:
        g64 = np.ascontiguousarray(grid, np.float64)
        b0 = np.array(bounds[0], np.float64)
        b1 = np.array(bounds[1], np.float64)
        runners["numba"] = lambda seed: lookup_sums(g64, b0, b1, n_items, n_lookups, seed)
    times = {name: [] for name in runners}
    for name, run in runners.items():
        run(0)  # compile / first launch
    for rep in range(repeats):  # alternate so drift hits every backend alike
        for name, run in runners.items():
            t = time.perf_counter()
            run(rep + 1)
            times[name].append(time.perf_counter() - t)
    for name, ts in times.items():
        out[name] = n_items * n_lookups / float(np.median(ts))
    return out
