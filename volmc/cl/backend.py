"""The OpenCL render backend: builds the integrator specialised to the scene and launches it
in batches (same interface as the Numba backend)."""

import numpy as np

from ..pack import medium_array, pack_majorant, pack_scene
from ..params import N_COUNTERS
from ..scene.features import define_flags, features
from .context import cl_context

#: Work-group size of the render kernel (None lets the driver choose). On PoCL, 1 is about
#: 1.2x faster than the driver default for these divergent loops (`volmc bench workgroup`).
DEFAULT_LOCAL_SIZE = 1


class OpenCLBackend:
    """Renders a scene with kernels/integrator.cl on one OpenCL device."""

    name = "opencl"

    def __init__(self, scene, device=None, feature_set=None, local_size=DEFAULT_LOCAL_SIZE,
                 options=()):
        self.scene = scene
        self.clc = cl_context(device)
        self.device = self.clc.device
        needed = features(scene)
        self.features = needed if feature_set is None else frozenset(feature_set)
        if not needed <= self.features:
            raise ValueError(f"a build without {', '.join(sorted(needed - self.features))} "
                             "cannot render this scene")
        from ..reference.estimators import ESTIMATORS
        est = scene.render.transmittance
        self.options = define_flags(self.features) + [
            f"-DSHADOW_ESTIMATOR={ESTIMATORS[est][1]}"] + list(options)
        if est == "biased_raymarch":
            self.options.append("-DSHADOW_ESTIMATOR_EXTRA=,1.0f")
        self.local_size = local_size
        params, lights, grid = pack_scene(scene, np.float32)
        if grid.size >= 2**31:
            raise ValueError(f"grid of {grid.size} voxels exceeds the kernels' 2^31 limit")
        self.params = params
        w, h = scene.camera.resolution
        self.n_pix = w * h
        clc = self.clc
        self.lights_buf = clc.to_device(lights)
        self.grid_buf = clc.to_device(grid)
        maj_max, maj_min = pack_majorant(scene, np.float32)
        self.maj_max_buf = clc.to_device(maj_max)
        self.maj_min_buf = clc.to_device(maj_min)
        self.med_buf = clc.to_device(medium_array(params), np.float32)
        nz, ny, nx = grid.shape
        self.dims = np.array([nx, ny, nz, 0], np.int32)
        # Batch outputs: per-pixel mean and sum of squared deviations (Welford).
        self.mean_host, self.mean_buf = clc.output((h, w, 3))
        self.m2_host, self.m2_buf = clc.output((h, w, 3))
        self.counters = np.zeros((self.n_pix, N_COUNTERS), np.uint64)
        self.cnt_buf = clc.to_device(self.counters, writable=True)
        self.program, self.build_how = clc.program("integrator.cl", self.options)
        self.kernel = clc.kernel(self.program, "render_batch")
        from ..reference.backend import techniques
        self.techniques = techniques(scene)
        self.techniques["features"] = " ".join(sorted(self.features)) or "none"

    def warm_up(self):
        """The program is built in the constructor; nothing left to compile."""

    def render(self, sample_start, n_samples, film):
        """Add samples [sample_start, sample_start + n_samples) of every pixel to ``film``."""
        self.clc.run(self.kernel, self.n_pix, self.local_size, self.params[0], self.lights_buf,
                     self.med_buf, self.grid_buf, self.dims, self.maj_max_buf, self.maj_min_buf,
                     np.uint32(sample_start), np.uint32(n_samples), self.mean_buf, self.m2_buf,
                     self.cnt_buf, outs=[(self.mean_host, self.mean_buf),
                                         (self.m2_host, self.m2_buf)])
        mean = self.mean_host.astype(np.float64)
        film.sum += n_samples * mean
        film.sum_sq += self.m2_host.astype(np.float64) + n_samples * mean * mean

    def counter_totals(self):
        """Counters summed over pixels (see params.COUNTER_NAMES)."""
        self.clc.read(self.counters, self.cnt_buf)
        return self.counters.sum(axis=0).astype(np.int64)
