"""The Numba float64 reference as a render backend (volmc/reference/integrator.py)."""

import numpy as np

from ..constants import RECORD_COLUMNS
from ..pack import pack_scene
from ..params import N_COUNTERS
from ..reference.integrator import render_batch
from .base import RenderBackend, new_segment_record, techniques


class NumbaBackend(RenderBackend):
    """Renders a scene with the float64 Numba path tracer."""

    name = "numba"

    def __init__(self, scene, record=0):
        """record: transmittance segments to record per pixel (0: none)."""
        self.scene = scene
        self.packed = pack_scene(scene, np.float64)
        w, h = scene.camera.resolution
        self.counters = np.zeros((w * h, N_COUNTERS), np.int64)
        self.techniques = techniques(scene)
        self.record = record
        # render_batch tells a record from the placeholder by its K + 1 > 1 rows.
        self.rec = (new_segment_record(w * h, record, np.float64) if record > 0
                    else np.zeros((1, 1, RECORD_COLUMNS)))

    def _launch(self, sample_start, n_samples, film_sum, film_sq, counters, rec):
        pk = self.packed
        render_batch(pk.params, pk.lights, pk.medium, pk.grid, pk.maj, pk.mnr, pk.emis,
                     pk.table, pk.bricks, pk.pool, pk.nodes, rec, sample_start, n_samples,
                     film_sum, film_sq, counters)

    def warm_up(self):
        film = np.zeros((1, 1, 3))
        self._launch(0, 0, film, film.copy(), np.zeros((1, N_COUNTERS), np.int64),
                     self.rec[:1])

    def render(self, sample_start, n_samples, film):
        self._launch(sample_start, n_samples, film.sum, film.sum_sq, self.counters, self.rec)

    def counter_totals(self):
        return self.counters.sum(axis=0)

    def segment_record(self):
        return self.rec.copy() if self.record > 0 else None
