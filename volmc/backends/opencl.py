"""The OpenCL render backend: kernels/integrator.cl built for the scene and launched in
batches on one device (volmc/cl/ has the host plumbing)."""

import math

import numpy as np

from ..cl.context import cl_context
from ..pack import env_buffer, pack_scene, shared_buffers
from ..cl.lanes import lane_options, resolve_gathers, resolve_lanes
from ..film import CHANNELS
from ..params import N_COUNTERS, launch_dtype, launch_spp
from ..scene.features import define_flags, features
from ..techniques import ESTIMATORS
from ..memory import band_rows as choose_band_rows
from ..memory import device_limits
from .base import RenderBackend, bands, new_segment_record, techniques

#: Work-group size of the render kernel (None lets the driver choose). On PoCL, 1 is about
#: 1.2x faster than the driver default for these divergent loops (`volmc bench workgroup`).
DEFAULT_LOCAL_SIZE = 1
#: Samples per work-item, in units of the lane width: at most JOB_ROUNDS, fewer when a launch
#: would otherwise give the device fewer than ITEMS_PER_UNIT work-items per compute unit, but
#: at least MIN_JOB_ROUNDS (which bounds the per-work-item counters at 1 byte per sample,
#: volmc.memory). A work-item's lanes idle while its last paths finish, so more rounds waste
#: less: 16 against 4 rounds is 1.12-1.15x the samples/s at W = 16 on the default cloud and
#: an fbm cloud, equal on the plume; 32 gains no more (alternating, 128x128, 64 spp).
JOB_ROUNDS = 16
MIN_JOB_ROUNDS = 4
ITEMS_PER_UNIT = 8
#: Jobs in a run of work-items that render consecutive blocks (item_deal).
DEAL_JOBS = 256


def accumulate_samples(x, channels):
    """(sum, sum of squares) over axis 1 of the float32 samples x[pixel, sample, :channels],
    in float64 and in sample order: the same numbers in the same order however the work was
    cut among lanes and work-items (and the same bits as numpy's ``sum(axis=1)`` of the
    float64 copy). One sample column at a time, so the temporaries are per pixel, not per
    sample (memory.CL_TEMP_BYTES_PER_CHANNEL): 3x to 5x faster than the float64 copy at 4 to
    16 samples per pixel."""
    total = x[:, 0, :channels].astype(np.float64)
    total_sq = total * total
    col = np.empty_like(total)
    for k in range(1, x.shape[1]):
        np.copyto(col, x[:, k, :channels])
        total += col
        col *= col
        total_sq += col
    return total, total_sq


def item_deal(n_items, jobs_per_item):
    """(stride, group): how render_batch deals a launch's n_items blocks of jobs_per_item
    jobs to its work-items. The blocks form runs of ``group`` consecutive blocks (about
    DEAL_JOBS jobs); of the n_items // group whole runs, work-item run r renders run
    (r x stride) mod (whole runs), and the work-items past them render their own blocks. The
    stride is coprime with the number of whole runs, so each block is rendered once, and
    near its count / phi (the golden ratio), so consecutive runs come from all over the
    launch (Fibonacci hashing).

    Why: PoCL's CPU driver hands its threads runs of consecutive work-groups, hundreds at a
    time (up to 512 for 2 threads in the PoCL 3.1 scheduler, as far as its source and the
    measured tails tell). At W = 8 a work-item holds 128 samples, so one run can be a
    quarter of a launch, and in row order a run over the costly middle of a cloud kept one
    core busy while the other idled: 1.67-1.82 of 2 cores busy on 96x96 fbm clouds at
    W = 8. Dealt this way 1.92-1.93, and 0.90x the time (alternating, 256 spp). Single
    work-items dealt apart lost cache locality at W = 1 (1.08x the time); runs of 256 jobs
    keep it (0.98-1.0x the time at W = 1). The image does not depend on the deal."""
    group = max(1, DEAL_JOBS // max(int(jobs_per_item), 1))
    runs = max(int(n_items) // group, 1)
    # Starts at most runs - 1 (or at 1), and runs - 1 is coprime with runs: the search ends
    # below runs.
    stride = max(1, round(runs * 0.6180339887498949))
    while math.gcd(stride, runs) != 1:
        stride += 1
    return stride, group


def render_options(feature_set, transmittance, options=()):
    """Build options of kernels/integrator.cl: the feature switches of ``feature_set``, the
    estimator functions of registry entry ``transmittance`` (VIEW_ESTIMATOR only where it
    differs from SHADOW_ESTIMATOR; SHADOW_TECHNIQUE where the shadow rays are walks of the
    tracking loop) and its build options, then ``options``."""
    est = ESTIMATORS[transmittance]
    return (define_flags(feature_set) + [f"-DSHADOW_ESTIMATOR={est.shadow_kernel}"]
            + ([f"-DSHADOW_TECHNIQUE={est.shadow_technique}"] if est.shadow_technique >= 0
               else [])
            + ([f"-DVIEW_ESTIMATOR={est.view_kernel}"]
               if est.view_kernel != est.shadow_kernel else [])
            + list(est.build_options) + list(options))


class OpenCLBackend(RenderBackend):
    """Renders a scene with kernels/integrator.cl on one OpenCL device, W paths per
    work-item (``lanes``)."""

    name = "opencl"

    def __init__(self, scene, device=None, feature_set=None, local_size=DEFAULT_LOCAL_SIZE,
                 options=(), record=0, band_rows=None, lanes=None,
                 jobs_per_item=None, albedo=False):
        """feature_set: the FEATURE_X switches to compile in (default: what the scene needs);
        options: more compiler options; local_size: the work-group size (None: driver's);
        record: transmittance segments to record per pixel (0: none; > 0 adds the RECORD
        switch to the build); band_rows: rows of pixels per launch (None:
        volmc.memory.band_rows for the device); lanes: paths per work-item (None:
        volmc.cl.lanes.resolve_lanes); jobs_per_item: samples per work-item (None: chosen
        per launch, ``launch_jobs_per_item``); albedo: also write the albedo AOV (adds the
        ALBEDO_AOV switch: each sample is then 8 floats, RGBA, the AOV and a pad)."""
        self.scene = scene
        self.albedo = bool(albedo)
        self.clc = cl_context(device)
        self.device = self.clc.device
        self.lanes = resolve_lanes(lanes, self.device)
        self.gathers = resolve_gathers(self.device)
        self.jobs_per_item = int(jobs_per_item) if jobs_per_item else None
        needed = features(scene)
        self.features = needed if feature_set is None else frozenset(feature_set)
        if record > 0:
            self.features = self.features | {"RECORD"}
        if self.albedo:
            self.features = self.features | {"ALBEDO_AOV"}
        self.stride = 8 if self.albedo else CHANNELS   # floats per sample (path_write)
        if not needed <= self.features:
            raise ValueError(f"a build without {', '.join(sorted(needed - self.features))} "
                             "cannot render this scene")
        pk = pack_scene(scene, np.float32)
        n_media = len(pk.parts)
        self.options = render_options(self.features, scene.render.transmittance,
                                      list(options) + lane_options(self.lanes, self.gathers)
                                      + ([f"-DMEDIA_COUNT={n_media}"] if n_media > 1 else []))
        self.local_size = local_size
        w, h = scene.camera.resolution
        for part in pk.parts:
            if part.grid.size >= 2**31 or part.emis.size >= 2**31:
                raise ValueError(f"grid of {max(part.grid.size, part.emis.size)} voxels exceeds "
                                 "the kernels' 2^31 limit for dense grids (use "
                                 "render.grid_storage = \"bricks\")")
        media, grid, maj, mnr, emis, table, bricks, pool, nodes = shared_buffers(pk)
        self.params, self.medium = pk.params, media
        self.n_pix = w * h
        self.band_rows = (choose_band_rows(w, h, self.name,
                                           max_alloc=device_limits(self.device)[1],
                                           albedo=self.albedo)
                          if band_rows is None else max(1, min(int(band_rows), h)))
        clc = self.clc
        self.lights_buf = clc.to_device(pk.lights)
        self.env_buf = clc.to_device(env_buffer(pk))   # float32: pk is
        self.grid_buf = clc.to_device(grid)
        self.maj_buf = clc.to_device(maj)
        self.mnr_buf = clc.to_device(mnr)
        self.emis_buf = clc.to_device(emis)
        self.table_buf = clc.to_device(table)
        self.bricks_buf = clc.to_device(bricks)
        self.pool_buf = clc.to_device(pool)
        self.nodes_buf = clc.to_device(nodes)
        self.record = record
        # Without recording the kernel gets capacity 0 and a 1-float dummy it never indexes.
        self.rec_host = (new_segment_record(w * h, record, np.float32) if record > 0
                         else np.zeros(1, np.float32))
        self.rec_buf = clc.to_device(self.rec_host, writable=True)
        # One launch's samples (float32 RGBA each) and its counters (one row per work-item),
        # sized for a band and the schedule's largest batch, grown if a caller asks for more.
        self.out_host = self.out_buf = self.cnt_host = self.cnt_buf = None
        self._reserve(self.band_rows * w * launch_spp(w * h))
        self.totals = np.zeros(N_COUNTERS, np.int64)
        self.program, self.build_how = clc.program("integrator.cl", self.options)
        self.kernel = clc.kernel(self.program, "render_batch")
        self.techniques = techniques(scene)
        self.techniques["features"] = " ".join(sorted(self.features)) or "none"
        self.techniques["lanes"] = str(self.lanes)

    def _reserve(self, n_jobs):
        """Output and counter buffers for launches of up to n_jobs samples."""
        if self.out_host is not None and len(self.out_host) >= n_jobs:
            return
        self.out_host, self.out_buf = self.clc.output((n_jobs, self.stride))
        items = -(-n_jobs // min(self.launch_jobs_per_item(1), MIN_JOB_ROUNDS * self.lanes))
        self.cnt_host, self.cnt_buf = self.clc.output((items, N_COUNTERS), np.uint64)

    def launch_jobs_per_item(self, n_jobs):
        """Samples per work-item of a launch of n_jobs samples: the constructor's
        jobs_per_item, or JOB_ROUNDS x lanes, reduced towards MIN_JOB_ROUNDS x lanes so that
        the device gets ITEMS_PER_UNIT work-items per compute unit. The image does not depend
        on it (render_batch)."""
        if self.jobs_per_item:
            return self.jobs_per_item
        want = -(-n_jobs // (ITEMS_PER_UNIT * self.device.max_compute_units))
        rounds = min(JOB_ROUNDS, max(MIN_JOB_ROUNDS, -(-want // self.lanes)))
        return rounds * self.lanes

    def warm_up(self):
        """The program is built in the constructor; nothing left to compile."""

    def render(self, sample_start, n_samples, film):
        w = film.width
        for pix_start, n_pix in bands(w, film.height, self.band_rows):
            n_jobs = n_pix * n_samples
            if n_jobs == 0:
                continue
            self._reserve(n_jobs)
            jobs = self.launch_jobs_per_item(n_jobs)
            items = -(-n_jobs // jobs)
            launch = np.zeros(1, launch_dtype())
            launch[0] = (pix_start, n_pix, sample_start, n_samples, jobs,
                         *item_deal(items, jobs), self.record)
            # The records as they are now (a few hundred bytes per medium; tests edit them).
            self.media_buf = self.clc.to_device(self.medium)
            self.clc.run(self.kernel, items, self.local_size, self.params[0], self.media_buf,
                         launch[0], self.lights_buf, self.env_buf, self.grid_buf, self.maj_buf,
                         self.mnr_buf,
                         self.emis_buf, self.table_buf, self.bricks_buf, self.pool_buf,
                         self.nodes_buf, self.rec_buf, self.out_buf, self.cnt_buf,
                         outs=[(self.out_host, self.out_buf), (self.cnt_host, self.cnt_buf)])
            rows = slice(pix_start // w, (pix_start + n_pix) // w)
            x = self.out_host[:n_jobs].reshape(n_pix, n_samples, self.stride)
            total, total_sq = accumulate_samples(x, film.channels)
            film.sum[rows] += total.reshape(-1, w, film.channels)
            film.sum_sq[rows] += total_sq.reshape(-1, w, film.channels)
            self.totals += self.cnt_host[:items].sum(axis=0).astype(np.int64)

    def counter_totals(self):
        return self.totals.copy()

    def segment_record(self):
        if self.record <= 0:
            return None
        self.clc.read(self.rec_host, self.rec_buf)
        return self.rec_host.astype(np.float64)
