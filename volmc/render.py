"""Render driver: batches of samples, progress bar, Ctrl-C, statistics.

Samples are indexed globally (sample s of pixel p always uses the same random numbers).
Batch sizes follow a fixed schedule that depends only on the image size (1, 2, 4, ...
samples per pixel, up to about BATCH_SAMPLES samples per batch), never on timing, and
batches are grouped into chunks of about CHUNK_SAMPLES samples, each summed into an empty
film and then added to the render's film. So the floating-point summation order, and
therefore the image, is bit-for-bit reproducible, whether the chunks run here, on a Dask
cluster (distributed.py) or after a resume from a checkpoint. The progress bar moves, and
Ctrl-C and checkpoints act, between chunks (about a second of work at the default
scene's speed).
"""

import signal
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from .backends import make_backend
from .distributed import ClusterError
from .film import Film
from .memory import check_memory
from .params import BATCH_SAMPLES, COUNTER_NAMES, launch_spp  # noqa: F401 (re-exported)

def batch_schedule(n_pixels, spp, start=0):
    """Samples per pixel of each batch: 1, 2, 4, ... up to BATCH_SAMPLES / n_pixels.

    start: samples per pixel already done (a resumed render); the batches returned cover
    [start, spp) and are the schedule's own batches from there on (the rest of the batch
    ``start`` falls in first, when it is not at a batch boundary)."""
    cap = launch_spp(n_pixels)
    out, size, done = [], 1, 0
    while done < spp:
        n = min(size, cap, spp - done)
        if done + n > start:
            out.append(done + n - max(done, start))
        done += n
        size *= 2
    return out

#: Samples a chunk groups: the batches of a chunk are summed into an empty film and the
#: chunk's sums are added to the render's film in one step, on one machine or on a cluster
#: (where a chunk is one task), so both add the same numbers in the same order.
CHUNK_SAMPLES = 1 << 19

#: Seconds between checkpoints unless the caller says otherwise (render, --checkpoint-every;
#: volmc.render's default is the same number, tests/test_api.py).
CHECKPOINT_EVERY = 60.0


def chunk_schedule(n_pixels, spp, start=0, chunk_samples=CHUNK_SAMPLES):
    """The batches of [start, spp) grouped into chunks: a list of chunks, each a list of
    (sample_start, n_samples) batches of ``batch_schedule``. Chunks are formed from sample
    0 on -- consecutive batches until they hold at least ``chunk_samples`` samples (pixels
    x samples per pixel) -- so a render resumed at a chunk boundary meets the chunks of an
    uninterrupted one; a chunk ``start`` falls inside is cut to begin there."""
    chunks, cur, size, s = [], [], 0, 0
    for n in batch_schedule(n_pixels, spp):
        if s + n > start:
            cur.append((max(s, start), s + n - max(s, start)))
        s += n
        size += n * n_pixels
        if size >= chunk_samples:
            if cur:
                chunks.append(cur)
            cur, size = [], 0
    if cur:
        chunks.append(cur)
    return chunks


#: The float32 kernels' paths lose accuracy where a medium's mean free path is this small
#: a fraction of the scene frame's unit (a few float32 steps of the box's coordinates): an
#: emitting cube of optical depth 2e7 rendered 2.6 % dark, at 2e6 0.04 %.
FLOAT32_FREE_PATH = 2.0 ** -19


def precision_notes(scene, backend):
    """The note of a render on the float32 kernels whose densest medium's mean free path,
    in the scene frame (pack.scene_frame), is below FLOAT32_FREE_PATH: its paths' steps are
    then a few float32 steps of their positions, and the image drifts (the Numba backend
    renders in float64). Empty otherwise."""
    if backend != "opencl":
        return []
    from .pack import scene_frame
    from .scene.schema import ConstantDensity
    unit = scene_frame(scene)[1]
    top = 0.0
    for part in scene.media_scenes:
        m = part.spec.medium
        density = m.density.value if isinstance(m.density, ConstantDensity) else \
            float(part.grid.max())
        top = max(top, max(m.scale) * density * unit)
    if not top * FLOAT32_FREE_PATH > 1.0:
        return []
    return [f"a medium's extinction reaches {top:.3g} per unit of the frame the kernels "
            f"render in (its box's half-size): its mean free path is a few float32 steps of "
            f"the positions, so the OpenCL image loses accuracy (an emitting cube at 1e7 "
            f"rendered 2.6 % dark); the numba backend renders such a medium in float64"]


#: The guard counters a render reports when they are not 0, and what each count means.
GUARD_WARNINGS = (
    ("over_majorant", "density lookups exceeded the majorant (the image is biased: was the "
                      "density changed after the majorant was built?)"),
    ("capped", "walks were cut by render.max_steps"),
    ("dropped", "NaN, infinite or negative samples were dropped"),
)


@dataclass
class RenderResult:
    """A finished (or interrupted) render."""
    film: Film
    backend: str
    seconds: float
    partial: bool
    counters: dict
    techniques: dict
    spp_requested: int
    seed: int
    extra: dict = field(default_factory=dict)
    #: What went wrong around the render without spoiling it (a checkpoint that could not
    #: be written), one message each.
    notes: list = field(default_factory=list)

    @property
    def image(self):
        return self.film.mean()

    @property
    def alpha(self):
        """The coverage A = 1 - T per pixel [h, w]."""
        return self.film.alpha()

    def stats(self):
        """Derived statistics: samples/s, mean path length, lookups per sample, counters."""
        n = self.film.width * self.film.height * self.film.spp
        c = self.counters
        out = {
            "samples": n,
            "samples_per_second": n / self.seconds if self.seconds > 0 else float("nan"),
            "mean_path_length": c["scatter_events"] / max(n, 1),
            "lookups_per_sample": c["lookups"] / max(n, 1),
            "shadow_rays_per_sample": c["shadow_rays"] / max(n, 1),
            "paths_capped": c["capped"],
            "dropped_contributions": c["dropped"],
            "lookups_over_majorant": c["over_majorant"],
        }
        # OpenCL: the lane width and the lanes' occupancy, the mean fraction of them active
        # in an iteration of the tracking loop.
        lanes = int(self.techniques.get("lanes", 0))
        if lanes and c.get("lane_rounds"):
            out["lanes"] = lanes
            out["lane_occupancy"] = c["lane_active"] / (c["lane_rounds"] * lanes)
        return out

    def guard_warnings(self):
        """One message per guard that fired during the render (lookups above the majorant,
        walks cut by render.max_steps, dropped samples), with its count: the image may then
        be biased, and a render never is silently. Then the notes. Empty for a clean
        render."""
        c = self.counters
        return [f"{c[key]} {what}" for key, what in GUARD_WARNINGS
                if c.get(key, 0) > 0] + list(self.notes)

    def metadata(self):
        """EXR header metadata: spp, seed, backend, time, techniques, partial flag, counters."""
        meta = {
            "spp": self.film.spp,
            "spp_requested": self.spp_requested,
            "seed": str(self.seed),
            "backend": self.backend,
            "render_time_s": float(self.seconds),
            "partial": int(self.partial),
        }
        meta.update({f"technique.{k}": v for k, v in self.techniques.items()})
        meta.update({f"count.{k}": str(v) for k, v in self.counters.items()})
        meta.update(self.extra)
        return meta


class _StopFlag:
    """SIGINT handler that asks the loop to stop after the current chunk."""

    def __init__(self):
        self.stop = False
        self._old = None

    def __enter__(self):
        try:
            self._old = signal.signal(signal.SIGINT, self._handle)
        except ValueError:  # not the main thread: leave signals alone
            self._old = None
        return self

    def _handle(self, signum, frame):
        if self.stop:  # second Ctrl-C: give up on the current chunk too
            raise KeyboardInterrupt
        self.stop = True

    def __exit__(self, *exc):
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
        return False


def whole(result):
    """``result`` (render's RenderResult, or volmc.render's RenderedImage) when it is
    complete; KeyboardInterrupt when it is partial. render turns Ctrl-C into a partial
    result, which a benchmark or a comparison has no use for: it must stop, as Ctrl-C asks,
    and not report a reference of fewer samples than it says."""
    if result.partial:
        raise KeyboardInterrupt
    return result


def render(scene, backend="opencl", spp=None, progress=None, on_start=None, checkpoint=None,
           checkpoint_every=CHECKPOINT_EVERY, resume=None, client=None, device=None,
           chunk_samples=CHUNK_SAMPLES, band_rows=None, lanes=None, label=None, albedo=False):
    """Render ``scene`` with ``backend``; returns a RenderResult (partial if interrupted).

    spp: samples per pixel (default: scene.render.spp). progress: show a tqdm bar (default:
    when stderr is a terminal). on_start: called once the backend is compiled and the
    Ctrl-C handler is installed, just before the first chunk. checkpoint: a path to write
    checkpoints to (checkpoint.py) between chunks, every ``checkpoint_every`` seconds of
    wall time and at the end (also when interrupted). resume: a checkpoint to continue from;
    it must be of this scene, seed, sampler and backend (SceneError otherwise), and the
    result equals an uninterrupted render bit for bit. client: a dask.distributed Client;
    the chunks then run as tasks on its workers (distributed.py; ``backend`` must be a
    name, ``device`` the OpenCL device there) and the image is the same bit for bit.
    chunk_samples: the chunk size of ``chunk_schedule``; progress, Ctrl-C and checkpoints
    act between chunks. band_rows: rows of pixels per launch of a backend made here (None:
    volmc.memory.band_rows). lanes: OpenCL's paths per work-item (None:
    volmc.cl.lanes.resolve_lanes here, also for a cluster, whose workers render with it); it
    is part of a checkpoint's identity. label: the progress bar's title (a frame sequence's
    "frame 3/48"). albedo: the film also accumulates the albedo AOV a denoiser reads
    (film.py; a backend given here must have been made with it).

    Before any work, ``volmc.memory.check_memory`` raises SceneError (naming the key, the
    memory needed and the memory there is) when the render would not fit; given a backend
    already made, or rendering on a cluster, only the film is left to check here (each
    worker checks the scene and its backend against its own memory before it builds them,
    distributed._render_task).
    """
    from tqdm import tqdm
    from . import checkpoint as ckpt
    spp = scene.render.spp if spp is None else int(spp)
    name = backend if isinstance(backend, str) else backend.name
    if client is not None:
        check_memory(scene, name, device, band_rows, scene_data=False, albedo=albedo)
    elif isinstance(backend, str):
        check_memory(scene, backend, device, band_rows, albedo=albedo)
    else:
        albedo = getattr(backend, "albedo", False)
        check_memory(scene, backend.name, getattr(backend, "device", None),
                     getattr(backend, "band_rows", None), scene_data=False, albedo=albedo)
    if name == "opencl":
        from .cl.lanes import resolve_lanes
        lanes = backend.lanes if not isinstance(backend, str) else \
            resolve_lanes(lanes, None if client is not None else device)
    else:
        lanes = None
    w, h = scene.camera.resolution
    film, prior, elapsed = Film(w, h, albedo), dict.fromkeys(COUNTER_NAMES, 0), 0.0
    if resume is not None:
        film, prior, elapsed = ckpt.load(resume, scene, name, lanes, albedo)
    ident = ckpt.identity(scene, name, lanes) if checkpoint is not None else None
    chunks = chunk_schedule(w * h, spp, film.spp, chunk_samples)
    if client is not None:
        from .distributed import ClusterChunks
        runner = ClusterChunks(client, scene, name, device, film, chunks, lanes, albedo)
    else:
        be = (make_backend(backend, scene, device, band_rows=band_rows, lanes=lanes,
                           albedo=albedo)
              if isinstance(backend, str) else backend)
        runner = LocalChunks(be, film, chunks)
    runner.warm_up()
    if progress is None:
        progress = sys.stderr.isatty()
    bar = tqdm(total=spp, initial=min(film.spp, spp), unit="spp", disable=not progress,
               leave=False, file=sys.stderr, desc=label)

    def counters():
        totals = runner.counter_totals()
        return {n: prior[n] + int(totals[i]) for i, n in enumerate(COUNTER_NAMES)}

    notes = []

    def save(seconds):
        # A checkpoint is insurance, not the result: a full disk or a directory gone
        # read-only must not end the render it protects. Tried again at the next interval.
        try:
            ckpt.save(checkpoint, film, counters(), seconds, ident)
        except OSError as e:
            if not notes:
                notes.append(f"{checkpoint}: the checkpoint could not be written "
                             f"({e.strerror or e}); the render went on without it")
            return False
        return True

    last_save = time.monotonic()
    failure = None
    with _StopFlag() as flag:
        if on_start is not None:
            on_start()
        t = time.perf_counter()
        runner.stopping = lambda: flag.stop   # a cluster awaiting a chunk stops on Ctrl-C
        try:
            for n in runner:   # each chunk is in the film when the runner yields
                film.spp += n
                bar.update(n)
                if checkpoint is not None and time.monotonic() - last_save >= checkpoint_every:
                    save(elapsed + time.perf_counter() - t)
                    last_save = time.monotonic()
                if flag.stop:
                    break
        except ClusterError as e:
            # The cluster failed: the chunks merged so far are kept, saved as after Ctrl-C,
            # and go out with the error (distributed.ClusterError.result).
            failure = e
        finally:
            runner.close()
        elapsed += time.perf_counter() - t
        stopped = (flag.stop or failure is not None) and film.spp < spp
    bar.close()
    if checkpoint is not None and save(elapsed):
        notes.clear()   # the last checkpoint holds all the work
    result = RenderResult(film, runner.name, elapsed, stopped, counters(), runner.techniques,
                          spp, scene.render.seed,
                          notes=notes + precision_notes(scene, runner.name))
    if failure is not None:
        failure.result = result
        raise failure
    return result


class LocalChunks:
    """The chunks of a render run in this process: iterating renders each chunk's batches
    into an empty film, adds that film's sums to the render's film and yields the chunk's
    samples per pixel."""

    def __init__(self, backend, film, chunks):
        self.be, self.film, self.chunks = backend, film, chunks
        self.name, self.techniques = backend.name, backend.techniques

    def warm_up(self):
        self.be.warm_up()

    def __iter__(self):
        for chunk in self.chunks:
            part = render_chunk(self.be, self.film.width, self.film.height, chunk)
            self.film.sum += part.sum
            self.film.sum_sq += part.sum_sq
            yield part.spp

    def counter_totals(self):
        return self.be.counter_totals()

    def close(self):
        pass


def render_chunk(backend, width, height, chunk):
    """A Film holding the batches (sample_start, n_samples) of ``chunk`` rendered by
    ``backend`` in order into an empty film (what a cluster task returns too)."""
    part = Film(width, height, getattr(backend, "albedo", False))
    for start, n in chunk:
        backend.render(start, n, part)
        part.spp += n
    return part


def mean_and_stderr(result):
    """(image mean over pixels per channel, its standard error) of a render."""
    img = result.film.mean()
    var = result.film.variance_of_mean()
    n_pix = img.shape[0] * img.shape[1]
    return img.mean(axis=(0, 1)), np.sqrt(var.sum(axis=(0, 1))) / n_pix
