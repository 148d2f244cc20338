"""Render driver: batches of samples, progress bar, Ctrl-C, statistics.

Samples are indexed globally (sample s of pixel p always uses the same random numbers).
Batch sizes follow a fixed schedule that depends only on the image size (1, 2, 4, ...
samples per pixel, up to about BATCH_SAMPLES samples per batch), never on timing, so the
floating-point summation order, and therefore the image, is bit-for-bit reproducible. The
progress bar moves and Ctrl-C is honoured between batches.
"""

import signal
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from .backends import make_backend
from .film import Film
from .memory import check_memory
from .params import COUNTER_NAMES

#: Samples (pixels x samples per pixel) per batch once the schedule has ramped up: about a
#: second of work at the default scene's speed, so Ctrl-C answers within about a second.
BATCH_SAMPLES = 1 << 16


def batch_schedule(n_pixels, spp):
    """Samples per pixel of each batch: 1, 2, 4, ... up to BATCH_SAMPLES / n_pixels."""
    cap = max(1, BATCH_SAMPLES // max(n_pixels, 1))
    out, size, done = [], 1, 0
    while done < spp:
        n = min(size, cap, spp - done)
        out.append(n)
        done += n
        size *= 2
    return out

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

    @property
    def image(self):
        return self.film.mean()

    def stats(self):
        """Derived statistics: samples/s, mean path length, lookups per sample, counters."""
        n = self.film.width * self.film.height * self.film.spp
        c = self.counters
        return {
            "samples": n,
            "samples_per_second": n / self.seconds if self.seconds > 0 else float("nan"),
            "mean_path_length": c["scatter_events"] / max(n, 1),
            "lookups_per_sample": c["lookups"] / max(n, 1),
            "shadow_rays_per_sample": c["shadow_rays"] / max(n, 1),
            "paths_capped": c["capped"],
            "dropped_contributions": c["dropped"],
            "lookups_over_majorant": c["over_majorant"],
        }

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
    """SIGINT handler that asks the loop to stop after the current batch."""

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
        if self.stop:  # second Ctrl-C: give up on the current batch too
            raise KeyboardInterrupt
        self.stop = True

    def __exit__(self, *exc):
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
        return False


def render(scene, backend="opencl", spp=None, progress=None, on_start=None, band_rows=None):
    """Render ``scene`` with ``backend``; returns a RenderResult (partial if interrupted).

    spp: samples per pixel (default: scene.render.spp). progress: show a tqdm bar (default:
    when stderr is a terminal). on_start: called once the backend is compiled and the
    Ctrl-C handler is installed, just before the first batch. band_rows: rows of pixels
    per launch of a backend made here (None: volmc.memory.band_rows).

    Before any work, ``volmc.memory.check_memory`` raises SceneError (naming the key, the
    memory needed and the memory there is) when the render would not fit; given a backend
    already made, only the film is left to check.
    """
    from tqdm import tqdm
    spp = scene.render.spp if spp is None else int(spp)
    if isinstance(backend, str):
        check_memory(scene, backend, rows=band_rows)
        be = make_backend(backend, scene, band_rows=band_rows)
    else:
        be = backend
        check_memory(scene, be.name, getattr(be, "device", None),
                     getattr(be, "band_rows", None), scene_data=False)
    be.warm_up()
    w, h = scene.camera.resolution
    film = Film(w, h)
    if progress is None:
        progress = sys.stderr.isatty()
    bar = tqdm(total=spp, unit="spp", disable=not progress, leave=False, file=sys.stderr)
    elapsed = 0.0
    with _StopFlag() as flag:
        if on_start is not None:
            on_start()
        for n in batch_schedule(w * h, spp):
            if flag.stop:
                break
            t = time.perf_counter()
            be.render(film.spp, n, film)
            elapsed += time.perf_counter() - t
            film.spp += n
            bar.update(n)
        stopped = flag.stop and film.spp < spp
    bar.close()
    totals = be.counter_totals()
    counters = {name: int(totals[i]) for i, name in enumerate(COUNTER_NAMES)}
    return RenderResult(film, be.name, elapsed, stopped, counters, be.techniques, spp,
                        scene.render.seed)


def mean_and_stderr(result):
    """(image mean over pixels per channel, its standard error) of a render."""
    img = result.film.mean()
    var = result.film.variance_of_mean()
    n_pix = img.shape[0] * img.shape[1]
    return img.mean(axis=(0, 1)), np.sqrt(var.sum(axis=(0, 1))) / n_pix
