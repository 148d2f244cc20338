"""Run a registered transmittance estimator on batches of rays with either backend.

Both runners take the same arguments: ``med``, a medium record (volmc/reference/medium.py:
``make_profile`` or ``make_grid_medium``) shared by every ray, or an array with one record
per ray; ``grid``, the density grid (any 1x1x1 array for profiles); ``rays`` [r, 9] (o, d,
t0, t1, pad); ``bounds`` [r, 2], each ray's extinction majorant and minorant (the medium's
global majorant is set to them); ``n_per_ray`` estimates per ray; the seed and the first
sample index. Given ``maj`` and ``mnr`` (the density maxima and minima of the medium's
majorant grid, or of its octree with ``nodes``, as pack.py builds them), the records keep
their own majorant kind and fields and ``bounds`` is ignored (may be None): the estimators
then walk the majorant structure a render walks. They return (estimates float64
[r * n_per_ray], counters int64 [r * n_per_ray, N_COUNTERS]); estimate i uses ray i // n_per_ray and sample index
sample_offset + i % n_per_ray on STREAM_TEST, on both backends alike. A runner made with
``chromatic=True`` returns RGB estimates [r * n_per_ray, 3] (media with colour-dependent
extinction, ``chroma`` < 1; the OpenCL build then has FEATURE_CHROMATIC); otherwise the
first channel. A runner made with ``shadow=True`` runs the estimator's shadow-ray twins
(``Estimator.shadow_function``: what a render runs on the shadow rays of scattering paths;
the same as the estimator itself except for "auto").
"""

import numpy as np

from ..constants import MAJORANT_GLOBAL
from ..params import N_COUNTERS, medium_dtype
from ..reference import estimators as E
from ..techniques import ESTIMATORS

MAX_STEPS = 1_000_000
_NO_MAJORANT_GRID = np.zeros((1, 1, 1))
_NO_NODES = np.zeros(1, np.int32)


def ray_media(med, grid, rays, bounds, real):
    """One medium record per ray (``real`` precision) with the ray's bounds as its global
    majorant and minorant (``bounds`` None: the record's own majorant structure is kept),
    and the grid's dimensions."""
    med = np.atleast_1d(np.asarray(med))
    media = np.zeros(len(rays), medium_dtype(real))
    for name in media.dtype.names:
        media[name] = med[name] if len(med) > 1 else med[name][0]
    if bounds is not None:
        b = np.asarray(bounds, np.float64).reshape(len(rays), 2)
        media["sigma_maj"], media["sigma_min"] = b[:, 0], b[:, 1]
        media["majorant_kind"] = MAJORANT_GLOBAL
    nz, ny, nx = np.shape(grid)
    media["dims"] = (nx, ny, nz)
    return media


def _structure(maj, mnr, nodes, real):
    """(maj, mnr, nodes) arrays for a launch: the given structure, or placeholders."""
    if maj is None:
        return _NO_MAJORANT_GRID.astype(real), _NO_MAJORANT_GRID.astype(real), _NO_NODES
    return (np.ascontiguousarray(maj, real), np.ascontiguousarray(mnr, real),
            np.ascontiguousarray(_NO_NODES if nodes is None else nodes, np.int32))


class _Runner:
    """What both runners share: ``run`` is ``prepare`` (records, copies, allocations: what a
    benchmark does before it starts the clock) then ``launch`` (the estimates and their
    read-back: what it times)."""

    def run(self, med, grid, rays, bounds, n_per_ray, seed=0, sample_offset=0, maj=None,
            mnr=None, nodes=None):
        return self.launch(self.prepare(med, grid, rays, bounds, n_per_ray, seed,
                                        sample_offset, maj, mnr, nodes))


class NumbaEstimator(_Runner):
    """One estimator run by the Numba reference (``reference.estimators.estimate_batch``)."""

    backend = "numba"

    def __init__(self, name, device=None, chromatic=False, shadow=False):
        self.est = ESTIMATORS[name]
        self.chromatic = chromatic
        self.id = self.est.shadow_estimator_id if shadow else self.est.id

    def prepare(self, med, grid, rays, bounds, n_per_ray, seed=0, sample_offset=0, maj=None,
                mnr=None, nodes=None):
        """``run``'s arguments in the form the estimates read: what a benchmark does before
        it starts the clock (``launch`` is what it times)."""
        media = ray_media(med, grid, rays, None if maj is not None else bounds, np.float64)
        maj, mnr, nodes = _structure(maj, mnr, nodes, np.float64)
        return (media, np.ascontiguousarray(grid, np.float64), maj, mnr, nodes,
                np.ascontiguousarray(rays, np.float64), n_per_ray, np.uint64(seed),
                sample_offset)

    def launch(self, prepared):
        """The estimates of a ``prepare``d batch: (estimates, counters), as ``run``."""
        media, grid, maj, mnr, nodes, rays, n_per_ray, seed, offset = prepared
        out, cnt = E.estimate_batch(self.id, media, grid, maj, mnr, nodes, rays, n_per_ray,
                                    seed, offset, MAX_STEPS)
        return (out if self.chromatic else out[:, 0].copy()), cnt


def estimator_options(name, chromatic=False, shadow=False):
    """Build options of kernels/estimators.cl for estimator ``name`` (its shadow-ray function
    if ``shadow``). The benchmark's media are grey and emit nothing: the build says so, as a
    render build of a grey scene does, so the timed loop is the production one."""
    est = ESTIMATORS[name]
    fn = est.shadow_kernel if shadow else est.kernel
    return ([f"-DESTIMATOR={fn}", f"-DFEATURE_CHROMATIC={int(chromatic)}",
             "-DFEATURE_EMISSION=0"] + list(est.build_options))


class OpenCLEstimator(_Runner):
    """One estimator compiled into kernels/estimators.cl on the default (or given) device."""

    backend = "opencl"

    def __init__(self, name, device=None, chromatic=False, shadow=False, lanes=None):
        from ..cl.context import cl_context
        from ..cl.lanes import lane_options, resolve_gathers, resolve_lanes
        self.est = ESTIMATORS[name]
        self.chromatic = chromatic
        self.clc = cl_context(device)
        self.lanes = resolve_lanes(lanes, self.clc.device)
        gathers = resolve_gathers(self.clc.device)
        self.program, _ = self.clc.program("estimators.cl",
                                           estimator_options(name, chromatic, shadow)
                                           + lane_options(self.lanes, gathers))
        self.kernel = self.clc.kernel(self.program, "estimate_batch")

    def prepare(self, med, grid, rays, bounds, n_per_ray, seed=0, sample_offset=0, maj=None,
                mnr=None, nodes=None):
        """The device buffers of a batch (NumbaEstimator.prepare): the records, the grid and
        the rays copied to the device and the outputs allocated, before the clock starts."""
        clc = self.clc
        media = ray_media(med, grid, rays, None if maj is not None else bounds, np.float32)
        maj, mnr, nodes = _structure(maj, mnr, nodes, np.float32)
        n = len(rays) * n_per_ray
        out, ob = clc.output((n, 3) if self.chromatic else n, np.float32)
        cnt, cb = clc.output((n, N_COUNTERS), np.uint64)
        args = (clc.to_device(media), clc.to_device(grid, np.float32), clc.to_device(maj),
                clc.to_device(mnr), clc.to_device(nodes), clc.to_device(rays, np.float32),
                np.int32(n_per_ray), np.uint64(seed), np.uint32(sample_offset),
                np.int32(MAX_STEPS), ob, cb)
        clc.queue.finish()   # the copies are done before the clock starts
        return len(rays), n_per_ray, args, [(out, ob), (cnt, cb)]

    def launch(self, prepared):
        """Runs a ``prepare``d batch and reads its results back: (estimates, counters)."""
        n_rays, n_per_ray, args, outs = prepared
        out, cnt = self.clc.run_rays(self.kernel, n_rays, n_per_ray, self.lanes, *args,
                                     outs=outs)
        return out.astype(np.float64), cnt.astype(np.int64)


def estimator(backend, name, device=None, chromatic=False, shadow=False, lanes=None):
    """The runner of estimator ``name`` on ``backend`` ("numba" or "opencl"; ``lanes``: its
    lane width, None: the default)."""
    if backend == "numba":
        return NumbaEstimator(name, device, chromatic, shadow)
    return OpenCLEstimator(name, device, chromatic, shadow, lanes)


def run_numba(name, med, grid, rays, bounds, n_per_ray, seed=0, sample_offset=0,
              chromatic=False, maj=None, mnr=None, nodes=None):
    """``NumbaEstimator(name, chromatic=chromatic).run(...)``."""
    return NumbaEstimator(name, chromatic=chromatic).run(med, grid, rays, bounds, n_per_ray,
                                                         seed, sample_offset, maj, mnr, nodes)
