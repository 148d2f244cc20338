"""The transmittance segments a real render queries, recorded and ready to replay.

A backend made with ``record=K`` renders as usual and keeps, per pixel, the first K segments
its samples hand to a transmittance estimate (reference/medium.py, ``record_segment``): the
camera segment (the primary ray clipped to the medium box, RECORD_CAMERA) and every shadow
ray as ``shadow_transmittance`` passes it to the estimator (RECORD_SHADOW), in the packed
scene frame (pack.scene_frame). ``record_segments`` runs that render and returns the
segments with the packed medium they were traced through, so the estimator runners
(transmittance_runner.py) can replay them on the scene's own majorant structure.
"""

from collections import namedtuple
from dataclasses import replace

import numpy as np

from ..constants import DENSITY_GRID, RECORD_CAMERA, RECORD_SHADOW

#: Segments of one render: ``camera`` and ``shadow`` float64 [n, 9] (o, d, t0, t1, kind, the
#: runners' ray layout) in the packed frame; ``counts`` int64 [n_pix, 2], the camera and
#: shadow segments recorded per pixel; the float64 packed medium record [1] (its majorant
#: kind and bounds as the render has them), density ``grid`` [nz, ny, nx] and majorant
#: structure ``maj``, ``mnr`` (and an octree's ``nodes``), as pack.py builds them; ``full``:
#: pixels whose record filled up (later segments of their samples were not kept).
Recording = namedtuple("Recording", ["camera", "shadow", "counts", "medium", "grid", "maj",
                                     "mnr", "nodes", "full"])


def with_resolution(scene, resolution):
    """``scene`` with camera.resolution = (width, height) (grids shared, not copied)."""
    from ..scene.loading import Scene
    spec = replace(scene.spec, camera=replace(scene.spec.camera,
                                              resolution=tuple(resolution)))
    return Scene(spec, scene.grid, scene.emission_grid)


def record_segments(scene, backend="opencl", spp=1, per_pixel=16, device=None, seed=0):
    """Render ``scene`` once (``spp`` samples per pixel, render.seed = ``seed``) with
    ``backend`` through the normal render path, recording up to ``per_pixel`` transmittance
    segments per pixel; returns a ``Recording``. The resolution is the scene's: shrink it
    first (``with_resolution``, or -D camera.resolution=[64, 64]) for a quick recording.

    Segments are float64 copies of what the backend traced (float32 values for "opencl").
    A dense density grid is required (the runners replay on dense grids), and one medium."""
    from ..backends import make_backend
    from ..scene.loading import require_one_medium
    require_one_medium(scene, "recording transmittance segments")
    from ..pack import pack_scene
    from ..render import render, whole
    if scene.grid is None:
        raise ValueError("recording needs a density grid (a homogeneous medium has no "
                         "transmittance segments worth replaying)")
    scene = scene.with_render(seed=seed)
    pk = pack_scene(scene, np.float64)
    if int(pk.medium[0]["density_kind"]) != DENSITY_GRID:
        raise ValueError("recording needs a dense density grid (render.grid_storage = "
                         "\"dense\")")
    be = make_backend(backend, scene, device, record=per_pixel)
    whole(render(scene, backend=be, spp=spp, progress=False))
    rec = be.segment_record()
    counts_total = rec[:, 0, 0].astype(np.int64)
    rows = rec[:, 1:, :]
    valid = np.arange(per_pixel)[None, :] < counts_total[:, None]
    kept = rows[valid]
    kind = kept[:, 8]
    counts = np.stack([(valid & (rows[:, :, 8] == RECORD_CAMERA)).sum(1),
                       (valid & (rows[:, :, 8] == RECORD_SHADOW)).sum(1)], 1)
    return Recording(kept[kind == RECORD_CAMERA].copy(), kept[kind == RECORD_SHADOW].copy(),
                     counts, pk.medium, pk.grid, pk.maj, pk.mnr, pk.nodes,
                     int(np.count_nonzero(counts_total >= per_pixel)))


def majorant_name(recording):
    """How the recording's medium bounds extinction, for reports: "grid majorant 16x16x16",
    "octree majorant (depth 5)" or "global majorant"."""
    from ..constants import MAJORANT_GRID, MAJORANT_OCTREE
    m = recording.medium[0]
    kind = int(m["majorant_kind"])
    if kind == MAJORANT_GRID:
        return "grid majorant " + "x".join(str(x) for x in recording.maj.shape[::-1])
    if kind == MAJORANT_OCTREE:
        return f"octree majorant (depth {int(m['octree_depth'])})"
    return "global majorant"
