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
        from ..cl.context import cl_context
        self.clc = cl_context(device)
        fn = ESTIMATORS[name][1]
        opts = [f"-DESTIMATOR={fn}"]
        if name == "biased_raymarch":
            opts.append(f"-DESTIMATOR_EXTRA=,{float(1.0 if extra is None else extra)!r}f")
        self.program, _ = self.clc.program("estimators.cl", opts)
        self.kernel = self.clc.kernel(self.program, "estimate_batch")

    def run(self, med, grid, rays, bounds, n_per_ray, seed=0, sample_offset=0):
        """Same contract as run_numba; returns (estimates float64, counters int64)."""
        clc = self.clc
        med = np.asarray(med, np.float32)
        if med.ndim == 1:
            med = np.repeat(med[None, :], len(rays), axis=0)
        grid = np.ascontiguousarray(grid, np.float32)
        nz, ny, nx = grid.shape
        n = len(rays) * n_per_ray
        out, ob = clc.output(n, np.float32)
        cnt, cb = clc.output((n, N_COUNTERS), np.uint64)
        clc.run(self.kernel, n, 1, clc.to_device(med, np.float32),
                clc.to_device(grid, np.float32), np.array([nx, ny, nz, 0], np.int32),
                clc.to_device(rays, np.float32), clc.to_device(bounds, np.float32),
                np.int32(n_per_ray), np.uint64(seed), np.uint32(sample_offset),
                np.int32(MAX_STEPS), ob, cb, outs=[(out, ob), (cnt, cb)])
        return out.astype(np.float64), cnt.astype(np.int64)
