"""The interface every render backend implements, and the backend registry.

A backend is built for one scene (it packs the scene with ``volmc.pack.pack_scene`` and
compiles what it needs), then renders batches of samples into a ``Film``. Samples are
indexed globally: sample s of pixel p always draws the same random numbers, so any split of
the work into batches gives the same image.
"""

import abc

import numpy as np

from ..constants import RECORD_COLUMNS, RR_MAX_SURVIVAL

#: Backend names, in the order tests and benchmarks use them: the production kernels first.
BACKENDS = ("opencl", "numba")


class RenderBackend(abc.ABC):
    """A renderer of one scene.

    ``name``: the backend's name (one of BACKENDS); ``scene``: the Scene it renders;
    ``techniques``: {what: how} for metadata and ``--stats`` (see ``techniques``)."""

    name = ""

    @abc.abstractmethod
    def warm_up(self):
        """Compile (or load from a cache) without rendering a sample."""

    @abc.abstractmethod
    def render(self, sample_start, n_samples, film):
        """Add samples [sample_start, sample_start + n_samples) of every pixel to ``film``
        (its per-pixel sums and sums of squares), launch by launch over bands of rows."""

    @abc.abstractmethod
    def counter_totals(self):
        """Counters summed over pixels since the backend was made: int64 [N_COUNTERS]
        (volmc.params.COUNTER_NAMES)."""

    @abc.abstractmethod
    def segment_record(self):
        """The transmittance segments recorded since the backend was made, float64
        [n_pix, K + 1, RECORD_COLUMNS] (reference/medium.py, ``record_segment``), for a
        backend made with ``record=K`` > 0; None otherwise."""


def new_segment_record(n_pix, capacity, real):
    """A zeroed segment record [n_pix, capacity + 1, RECORD_COLUMNS] of type ``real`` with
    each pixel's capacity in row 0, column 1 (the count, column 0, starts at 0)."""
    rec = np.zeros((n_pix, capacity + 1, RECORD_COLUMNS), real)
    rec[:, 0, 1] = capacity
    return rec


def bands(width, height, rows):
    """(first pixel, pixels) of each launch when an image is rendered in bands of ``rows``
    rows of pixels (row-major pixel indices)."""
    for y in range(0, height, rows):
        yield y * width, min(rows, height - y) * width


def make_backend(name, scene, device=None, record=0, band_rows=None, lanes=None,
                 albedo=False):
    """A render backend by name: "opencl" on ``device`` (None: the default device), or
    "numba"; ``record`` > 0 records up to that many transmittance segments per pixel
    (``segment_record``); ``band_rows``: rows of pixels per launch (None: as many as
    ``volmc.memory.band_rows`` allows; the image is the same whatever the bands);
    ``lanes``: OpenCL's paths per work-item (None: volmc.cl.lanes.resolve_lanes);
    ``albedo``: also accumulate the albedo AOV (film.py) into films made with it."""
    if name == "numba":
        from .numba import NumbaBackend
        return NumbaBackend(scene, record=record, band_rows=band_rows, albedo=albedo)
    if name == "opencl":
        from .opencl import OpenCLBackend
        return OpenCLBackend(scene, device=device, record=record, band_rows=band_rows,
                             lanes=lanes, albedo=albedo)
    raise ValueError(f"unknown backend {name!r} (available: {', '.join(BACKENDS)})")


def techniques(scene):
    """The technique choices a scene implies, for metadata and --stats."""
    media = scene.spec.media
    homogeneous = all(p.grid is None for p in scene.media_scenes)
    emits = [m.emission for m in media if m.emission is not None]
    r = scene.render
    flight = "delta tracking" if r.free_flight == "delta" or r.majorant == "global" else \
        "decomposition tracking"
    return {
        "free_flight": "analytic" if homogeneous else f"{flight} ({r.majorant} majorant)",
        "transmittance": "analytic" if homogeneous else
        f"{r.transmittance} ({r.majorant} majorant)",
        "phase": ", ".join(sorted({m.phase.type for m in media})),
        "spectral": ("grey" if not scene.spec.chromatic else
                     "spectral tracking" if r.spectral == "tracking" else
                     "hero-channel spectral MIS" if r.spectral == "hero" else
                     "one random channel per path"),
        "emission": ("none" if not emits else
                     ", ".join(sorted({"radiance x field" if e.radiance is not None else
                                       "blackbody temperature" for e in emits}))
                     + ", at every tentative collision"),
        "nee": f"all lights; environment by uniform sphere + {r.mis}-heuristic MIS",
        "russian_roulette": f"from depth {r.rr_depth}, q = min(max(beta), "
                            f"{RR_MAX_SURVIVAL if r.max_depth < 0 else 1})",
    }
