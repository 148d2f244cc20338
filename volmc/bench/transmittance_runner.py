"""Run transmittance estimators on batches of rays with either backend."""

import numpy as np

from ..params import N_COUNTERS
from ..reference import estimators as E

ESTIMATORS = E.ESTIMATORS

MAX_STEPS = 1_000_000


def run_numba(name, med, grid, rays, bounds, n_per_ray, seed=0, sample_offset=0, extra=1.0):
    """(estimates [n_rays * n_per_ray], counters [n, N_COUNTERS]) from the Numba reference.
    ``med`` is one extinction source (1-D) shared by every ray, or one row per ray."""
    est = ESTIMATORS[name][0]
    med = np.asarray(med, np.float64)
    if med.ndim == 1:
        med = np.repeat(med[None, :], len(rays), axis=0)
    return E.estimate_batch(est, np.ascontiguousarray(med), np.asarray(grid, np.float64),
                            np.asarray(rays, np.float64), np.asarray(bounds, np.float64),
                            n_per_ray, np.uint64(seed), sample_offset, MAX_STEPS, float(extra))


class OpenCLEstimator:
    """One estimator compiled into kernels/estimators.cl on the default (or given) device."""

    def __init__(self, name, device=None, extra=None):
        import pyopencl as cl

        from ..cl.build import assemble, build_program
        from ..cl.device import select_device
        self.cl = cl
        self.device = device if device is not None else select_device()
        self.ctx = cl.Context([self.device])
        self.queue = cl.CommandQueue(self.ctx)
        fn = ESTIMATORS[name][1]
        opts = [f"-DESTIMATOR={fn}"]
        if name == "biased_raymarch":
            opts.append(f"-DESTIMATOR_EXTRA=,{float(1.0 if extra is None else extra)!r}f")
        source = assemble("estimators.cl")
        self.program, _ = build_program(self.ctx, self.device, source, opts)
        self.kernel = self.cl.Kernel(self.program, "estimate_batch")

    def run(self, med, grid, rays, bounds, n_per_ray, seed=0, sample_offset=0):
        """Same contract as run_numba; returns (estimates float64, counters int64)."""
        cl = self.cl
        mf = cl.mem_flags

        def buf(a, dtype):
            a = np.ascontiguousarray(a, dtype)
            return cl.Buffer(self.ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)
        grid = np.ascontiguousarray(grid, np.float32)
        med = np.asarray(med, np.float32)
        if med.ndim == 1:
            med = np.repeat(med[None, :], len(rays), axis=0)
        nz, ny, nx = grid.shape
        n = len(rays) * n_per_ray
        out = np.empty(n, np.float32)
        cnt = np.empty((n, N_COUNTERS), np.uint64)
        ob = cl.Buffer(self.ctx, mf.WRITE_ONLY, out.nbytes)
        cb = cl.Buffer(self.ctx, mf.WRITE_ONLY, cnt.nbytes)
        self.kernel(self.queue, (n,), (1,), buf(med, np.float32), buf(grid, np.float32),
                    np.array([nx, ny, nz, 0], np.int32), buf(rays, np.float32),
                    buf(bounds, np.float32), np.int32(n_per_ray), np.uint64(seed),
                    np.uint32(sample_offset), np.int32(MAX_STEPS), ob, cb)
        cl.enqueue_copy(self.queue, out, ob)
        cl.enqueue_copy(self.queue, cnt, cb)
        self.queue.finish()
        return out.astype(np.float64), cnt.astype(np.int64)
