"""The Numba float64 reference as a render backend (volmc/reference/integrator.py)."""

from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from ..constants import RECORD_COLUMNS
from ..memory import band_rows as choose_band_rows
from ..pack import pack_scene
from ..params import N_COUNTERS
from ..film import CHANNELS
from ..reference.integrator import render_batch
from ..reference.medium import media_data
from .base import RenderBackend, bands, new_segment_record, techniques


class NumbaBackend(RenderBackend):
    """Renders a scene with the float64 Numba path tracer."""

    name = "numba"

    def __init__(self, scene, record=0, band_rows=None, albedo=False):
        """record: transmittance segments to record per pixel (0: none); band_rows: rows of
        pixels per launch (None: volmc.memory.band_rows); albedo: films of this backend hold
        the albedo AOV (render_pixel writes it into a film that has its channels)."""
        self.scene = scene
        self.albedo = bool(albedo)
        self.packed = pack_scene(scene, np.float64)
        self.media = media_data(self.packed)
        self.pool = ThreadPoolExecutor(max(1, numba.get_num_threads()))
        w, h = scene.camera.resolution
        self.band_rows = (choose_band_rows(w, h, self.name, albedo=albedo)
                          if band_rows is None else max(1, min(int(band_rows), h)))
        # Per-pixel counters of one band, summed into the totals after each launch.
        self.counters = np.zeros((self.band_rows * w, N_COUNTERS), np.int64)
        self.totals = np.zeros(N_COUNTERS, np.int64)
        self.techniques = techniques(scene)
        self.record = record
        # render_batch tells a record from the placeholder by its K + 1 > 1 rows.
        self.rec = (new_segment_record(w * h, record, np.float64) if record > 0
                    else np.zeros((1, 1, RECORD_COLUMNS)))

    def _launch(self, pix_start, n_pix, sample_start, n_samples, film_sum, film_sq, counters,
                rec):
        pk = self.packed
        self.media = media_data(pk)   # the records as they are now (tests edit them)
        # Pixel ranges on threads (render_batch releases the GIL), each writing its own film
        # pixels and counter rows.
        k = max(1, min(numba.get_num_threads(), n_pix))
        cuts = [n_pix * j // k for j in range(k + 1)]

        def part(j):
            a, b = cuts[j], cuts[j + 1]
            render_batch(pk.params, pk.lights, pk.env, self.media, rec, pix_start + a, b - a,
                         sample_start, n_samples, film_sum, film_sq, counters[a:b])
        if k == 1:
            part(0)
        else:
            list(self.pool.map(part, range(k)))

    def warm_up(self):
        film = np.zeros((1, 1, CHANNELS))
        self._launch(0, 1, 0, 0, film, film.copy(), np.zeros((1, N_COUNTERS), np.int64),
                     self.rec[:1])

    def render(self, sample_start, n_samples, film):
        for pix_start, n_pix in bands(film.width, film.height, self.band_rows):
            cnt = self.counters[:n_pix]
            self._launch(pix_start, n_pix, sample_start, n_samples, film.sum, film.sum_sq,
                         cnt, self.rec)
            self.totals += cnt.sum(axis=0)
            cnt[:] = 0

    def counter_totals(self):
        return self.totals.copy()

    def segment_record(self):
        return self.rec.copy() if self.record > 0 else None
