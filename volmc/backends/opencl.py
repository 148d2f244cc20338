"""The OpenCL render backend: kernels/integrator.cl built for the scene and launched in
batches on one device (volmc/cl/ has the host plumbing)."""

import numpy as np

from ..cl.context import cl_context
from ..pack import pack_scene
from ..params import N_COUNTERS
from ..scene.features import define_flags, features
from ..techniques import ESTIMATORS
from ..memory import band_rows as choose_band_rows
from ..memory import device_limits
from .base import RenderBackend, bands, new_segment_record, techniques

#: Work-group size of the render kernel (None lets the driver choose). On PoCL, 1 is about
#: 1.2x faster than the driver default for these divergent loops (`volmc bench workgroup`).
DEFAULT_LOCAL_SIZE = 1


def render_options(feature_set, transmittance, options=()):
    """Build options of kernels/integrator.cl: the feature switches of ``feature_set``, the
    estimator functions of registry entry ``transmittance`` (VIEW_ESTIMATOR only where it
    differs from SHADOW_ESTIMATOR) and its build options, then ``options``."""
    est = ESTIMATORS[transmittance]
    return (define_flags(feature_set) + [f"-DSHADOW_ESTIMATOR={est.shadow_kernel}"]
            + ([f"-DVIEW_ESTIMATOR={est.view_kernel}"]
               if est.view_kernel != est.shadow_kernel else [])
            + list(est.build_options) + list(options))


class OpenCLBackend(RenderBackend):
    """Renders a scene with kernels/integrator.cl on one OpenCL device."""

    name = "opencl"

    def __init__(self, scene, device=None, feature_set=None, local_size=DEFAULT_LOCAL_SIZE,
                 options=(), record=0, band_rows=None):
        """feature_set: the FEATURE_X switches to compile in (default: what the scene needs);
        options: more compiler options; local_size: the work-group size (None: driver's);
        record: transmittance segments to record per pixel (0: none; > 0 adds the RECORD
        switch to the build); band_rows: rows of pixels per launch (None:
        volmc.memory.band_rows for the device)."""
        self.scene = scene
        self.clc = cl_context(device)
        self.device = self.clc.device
        needed = features(scene)
        self.features = needed if feature_set is None else frozenset(feature_set)
        if record > 0:
            self.features = self.features | {"RECORD"}
        if not needed <= self.features:
            raise ValueError(f"a build without {', '.join(sorted(needed - self.features))} "
                             "cannot render this scene")
        pk = pack_scene(scene, np.float32)
        self.options = render_options(self.features, scene.render.transmittance, options)
        self.local_size = local_size
        w, h = scene.camera.resolution
        if pk.grid.size >= 2**31 or pk.emis.size >= 2**31:
            raise ValueError(f"grid of {max(pk.grid.size, pk.emis.size)} voxels exceeds the "
                             "kernels' 2^31 limit for dense grids (use render.grid_storage = "
                             "\"bricks\")")
        self.params, self.medium = pk.params, pk.medium
        self.n_pix = w * h
        self.band_rows = (choose_band_rows(w, h, self.name,
                                           max_alloc=device_limits(self.device)[1])
                          if band_rows is None else max(1, min(int(band_rows), h)))
        band = self.band_rows * w
        clc = self.clc
        self.lights_buf = clc.to_device(pk.lights)
        self.grid_buf = clc.to_device(pk.grid)
        self.maj_buf = clc.to_device(pk.maj)
        self.mnr_buf = clc.to_device(pk.mnr)
        self.emis_buf = clc.to_device(pk.emis)
        self.table_buf = clc.to_device(pk.table)
        self.bricks_buf = clc.to_device(pk.bricks)
        self.pool_buf = clc.to_device(pk.pool)
        self.nodes_buf = clc.to_device(pk.nodes)
        self.record = record
        # Without recording the kernel gets capacity 0 and a 1-float dummy it never indexes.
        self.rec_host = (new_segment_record(w * h, record, np.float32) if record > 0
                         else np.zeros(1, np.float32))
        self.rec_buf = clc.to_device(self.rec_host, writable=True)
        # Batch outputs of one band: per-pixel mean and sum of squared deviations (Welford),
        # and counters, summed into the totals after each launch.
        self.mean_host, self.mean_buf = clc.output((self.band_rows, w, 3))
        self.m2_host, self.m2_buf = clc.output((self.band_rows, w, 3))
        self.counters = np.zeros((band, N_COUNTERS), np.uint64)
        self.cnt_buf = clc.to_device(self.counters, writable=True)
        self.totals = np.zeros(N_COUNTERS, np.int64)
        self.program, self.build_how = clc.program("integrator.cl", self.options)
        self.kernel = clc.kernel(self.program, "render_batch")
        self.techniques = techniques(scene)
        self.techniques["features"] = " ".join(sorted(self.features)) or "none"

    def warm_up(self):
        """The program is built in the constructor; nothing left to compile."""

    def render(self, sample_start, n_samples, film):
        w = film.width
        for pix_start, n_pix in bands(w, film.height, self.band_rows):
            self.clc.run(self.kernel, n_pix, self.local_size, self.params[0], self.medium[0],
                         self.lights_buf, self.grid_buf, self.maj_buf, self.mnr_buf,
                         self.emis_buf, self.table_buf, self.bricks_buf, self.pool_buf,
                         self.nodes_buf, self.rec_buf, np.int32(self.record),
                         np.uint32(pix_start), np.uint32(n_pix), np.uint32(sample_start),
                         np.uint32(n_samples), self.mean_buf, self.m2_buf, self.cnt_buf,
                         outs=[(self.mean_host, self.mean_buf), (self.m2_host, self.m2_buf)])
            rows = slice(pix_start // w, (pix_start + n_pix) // w)
            k = n_pix // w
            mean = self.mean_host[:k].astype(np.float64)
            film.sum[rows] += n_samples * mean
            film.sum_sq[rows] += self.m2_host[:k].astype(np.float64) + n_samples * mean * mean
            if self.band_rows >= film.height:
                continue   # one band: the counters accumulate on the device
            # Counters are summed per launch, then the band's are zeroed for the next.
            self.clc.read(self.counters, self.cnt_buf)
            self.totals += self.counters[:n_pix].sum(axis=0).astype(np.int64)
            self.clc.cl.enqueue_fill_buffer(self.clc.queue, self.cnt_buf, np.uint64(0), 0,
                                            self.counters.nbytes).wait()

    def counter_totals(self):
        if self.band_rows >= self.scene.camera.resolution[1]:
            self.clc.read(self.counters, self.cnt_buf)
            return self.counters.sum(axis=0).astype(np.int64)
        return self.totals.copy()

    def segment_record(self):
        if self.record <= 0:
            return None
        self.clc.read(self.rec_host, self.rec_buf)
        return self.rec_host.astype(np.float64)
