"""The Numba reference as a render backend (same interface as the OpenCL one)."""

import numpy as np

from ..pack import medium_array, pack_majorant, pack_scene
from ..params import N_COUNTERS
from .integrator import render_batch


class NumbaBackend:
    """Renders a scene with the float64 Numba path tracer, in batches of samples per pixel."""

    name = "numba"

    def __init__(self, scene):
        self.scene = scene
        self.params, self.lights, self.grid = pack_scene(scene, np.float64)
        self.maj_max, self.maj_min = pack_majorant(scene, np.float64)
        self.med = medium_array(self.params)
        w, h = scene.camera.resolution
        self.counters = np.zeros((w * h, N_COUNTERS), np.int64)
        self.techniques = techniques(scene)

    def warm_up(self):
        """Compile (or load from Numba's cache) without rendering any sample."""
        film = np.zeros((1, 1, 3))
        render_batch(self.params, self.lights, self.med, self.grid, self.maj_max, self.maj_min,
                     0, 0, film, film.copy(), np.zeros((1, N_COUNTERS), np.int64))

    def render(self, sample_start, n_samples, film):
        """Add samples [sample_start, sample_start + n_samples) of every pixel to ``film``."""
        render_batch(self.params, self.lights, self.med, self.grid, self.maj_max, self.maj_min,
                     sample_start, n_samples, film.sum, film.sum_sq, self.counters)

    def counter_totals(self):
        """Counters summed over pixels, as a 1-D int64 array (see params.COUNTER_NAMES)."""
        return self.counters.sum(axis=0)


def techniques(scene):
    """The technique choices a scene implies, for metadata and --stats."""
    homogeneous = scene.grid is None
    return {
        "free_flight": "analytic" if homogeneous else
        f"delta tracking ({scene.render.majorant} majorant)",
        "transmittance": "analytic" if homogeneous else
        f"{scene.render.transmittance} ({scene.render.majorant} majorant)",
        "phase": scene.medium.phase.type,
        "nee": "all lights; environment by uniform sphere + balance-heuristic MIS",
        "russian_roulette": f"from depth {scene.render.rr_depth}, q = min(max(beta), 0.95)",
    }
