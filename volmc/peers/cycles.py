"""Blender Cycles as a peer renderer: translate a volmc scene, render it with Cycles (CPU).

Cycles runs in a child process (``volmc/peers/cycles_worker.py``, which imports ``bpy``):
this module writes a job (JSON, the grids as .npy), the worker builds the Blender scene,
renders it in passes of independent seeds and writes the pass images with Cycles' own
timings. ``bpy`` is optional (``pip install 'volmc[cycles]'``; its wheels need Python 3.11).

Conventions and how the translation matches them (each checked by tests/test_peer_cycles.py):

- **Camera.** Blender cameras look along their local -Z with +Y up; the camera's world
  matrix is built from ``look_at(eye, target, up)`` with +X to the right, as volmc's.
  ``fov`` is volmc's full vertical angle: ``sensor_fit = "VERTICAL"`` and ``angle_y``.
  volmc's orthographic ``size`` is the vertical extent: Blender's ``ortho_scale`` with the
  vertical sensor fit is the same length. A thin lens (``aperture`` > 0) is Blender's depth
  of field with a round aperture (``aperture_blades`` 0, ratio 1) focused at
  ``focus_distance``: Cycles' lens radius is lens x 1e-3 / (2 f-stop) for a perspective
  camera (lens: its focal length in mm, which ``angle`` sets) and 1 / (2 f-stop) for an
  orthographic one, so ``aperture_fstop`` is lens x 1e-3 / (2 aperture) or
  1 / (2 aperture); Cycles samples the disc uniformly and focuses on the plane at that
  distance along the view axis, as volmc. The panoramic camera is ``type = "PANO"`` with
  ``panorama_type = "EQUIRECTANGULAR"`` over its default 360 x 180 degrees (longitude and
  latitude ranges set explicitly): Cycles' middle column looks along the camera's view
  axis, with the same handedness as volmc's. Pixels are sampled uniformly with weight 1:
  Cycles' box filter of width 1 pixel. Cycles starts a perspective or orthographic camera's
  rays on the plane ``clip_start`` (1e-4) in front of the camera object, so the object sits
  that far behind volmc's eye and the rays start on the plane through the eye (a
  panorama's start on a sphere about the object: ``clip_start`` is Blender's smallest,
  1e-6, there). The output is Cycles' linear scene-referred EXR
  (the view transform does not touch it; "Standard" is set all the same).
- **Medium coefficients.** volmc: sigma_t = scale x density per channel,
  sigma_s = albedo sigma_t, sigma_a = (1 - albedo) sigma_t. Cycles' Volume Scatter gives
  sigma_s = density x colour, Volume Absorption sigma_a = density x (1 - colour); both get
  density = s x density(x), with s the largest channel of scale, and the colours k albedo
  and 1 - k (1 - albedo), k = scale / s (so colour-dependent extinction is Cycles' own
  chromatic medium). ``volume_biased = False``: Cycles' unbiased null-scattering tracking,
  not ray marching.
- **Grid.** volmc puts voxel (i, j, k) of the [z, y, x] array at the centre
  bmin + (i + 0.5) x voxel size (x fastest), interpolates trilinearly and clamps to the edge
  voxels inside the box; outside the box the density is 0. The grid goes to an OpenVDB
  float grid (through bpy's bundled ``openvdb``) whose index-to-world transform puts the
  centres there; Volume ``precision = "FULL"`` (not half floats) and ``clipping = 0`` (no
  value is dropped as empty). An emission field is a second grid of the same file with its
  own resolution and transform. OpenVDB interpolates towards its background 0 beyond the last
  voxel centre, so when any voxel on the grid's faces is non-zero the grid is written with
  one more layer of voxels copying the faces (volmc's clamping inside the box), and the
  shader multiplies the density by 1 inside ``medium.bounds`` and 0 outside (the padded
  layer's spill-over). A grid whose faces are all 0 needs neither.
- **Placement.** ``medium.transform`` is the medium object's ``matrix_world`` (world = M x
  object coordinates, where the box and the grid live). Cycles evaluates the volume shader at
  object coordinates and integrates along world distances, as volmc does; its object
  transforms handle a mirroring M (negative determinant) themselves. Blender keeps an
  object's matrix as a location, a rotation and a scale, so a sheared M (columns not
  orthogonal) is split by its singular values, M = T U S V^T: an empty at T U S, the
  medium its child turned by V^T (the worker's ``_place``). A volume object's
  densities are per world unit only with its render space set to "WORLD" (Blender's
  default, "OBJECT", scales them with the object: a grid stretched by 1.3 along the view
  rendered 0.903 for the closed form's 0.926; random-scene sweep, Cycles case 506).
- **Several media** (``[[media]]``): one Cycles object per medium (a volume object with its
  own VDB file, or a cube), each with its own material and ``matrix_world``; the job holds
  the first as ``medium`` and the rest as ``others``. Where objects overlap, Cycles' volume
  stack adds their closures: sigma_t, sigma_s and emission add, as in volmc, and a
  scattering event samples one phase function by its Volume Scatter closure's weight
  (sigma_s), while volmc picks the medium by its share of extinction and scatters with that
  medium's albedo. volmc's mix of phase functions is sigma_s,i[c] / sum sigma_s[c] in each
  channel c; Cycles picks the closure by one scalar weight for all channels and multiplies
  the throughput by the total sigma_s / sigma_t (its kernel says so: "we don't weight
  anisotropy properly depending on color channels"). The two agree when the overlapping
  media's albedos are proportional (sigma_s,i / sigma_s,j then does not depend on the
  channel, as the media share the chroma of their scale) or their phase functions are the
  same; otherwise Cycles is biased (+0.06 % in blue at 4096 spp on the overlapping test
  scene with unproportional albedos), so such overlapping media raise PeerUnavailable.
  Overlap is decided by separating axes of the placed boxes (mitsuba.boxes_overlap).
- **Transparent background.** ``render.transparent_background`` is Cycles' Film >
  Transparent (``film_transparent``): camera rays do not see the world, which still lights
  the medium; Cycles' EXR RGB is premultiplied, as volmc's.
- **Homogeneous medium.** A cube mesh spanning ``medium.bounds`` with the volume material
  and no surface shader (its faces are transparent); a camera inside it is inside the
  medium, which Cycles detects itself.
- **Phase.** Henyey-Greenstein with g > 0 scattering forward in both.
- **Lights.** ``environment`` is the world background (radiance, strength 1; several add
  up). ``directional`` is a sun of angle 0 whose -Z axis is volmc's direction of travel; a
  sun's strength is its irradiance in W/m^2 (colour normalised to its largest channel,
  strength that channel). ``point`` is a point light of radius 0; Blender gives its power
  P in watts, and the radiant intensity Cycles emits is P / POINT_POWER_PER_INTENSITY, so
  P = POINT_POWER_PER_INTENSITY x volmc's intensity (the factor is checked against volmc in
  the tests). Light-tree threshold 0 (no light is culled).
- **Emission.** volmc's source term is sigma_a(x) Le(x); Cycles' volume Emission adds
  colour x strength per unit length as it is. For ``radiance`` x ``field`` emission the
  Emission colour is (1 - albedo) x scale x radiance per channel (normalised, its largest
  value moved into the strength) and the strength density(x) x field(x), both grids read
  from one VDB file. Blackbody ``temperature`` emission is not translated (raises
  PeerUnavailable): Cycles' Blackbody node gives a normalised colour, not volmc's radiance
  in nits, and a temperature interpolated before the table is not a colour interpolated
  after it.
- **Path depth.** volmc's ``max_depth`` counts scattering events, with direct light at
  each; Cycles' ``volume_bounces`` counts the bounces after the first scattering event's
  direct light, so it gets max_depth - 1 (-1, unbounded, becomes Cycles' largest, 1024).
  max_depth = 0 (a scattering event ends the path) becomes a medium whose scattering is
  absorption: albedo 0 for the coefficients, with the emission kept as it was.
- **No clamping, denoising or adaptive sampling**; the seed of each pass is Cycles' seed.

Timing: Cycles reports its phases through ``render_stats``: scene sync first (object and
volume updates, building the majorant structure), then "Sample i/N" while it traces. The
worker reports each pass's tracing time (from the start of the first sample, estimated from
the first report, to "Finished") apart from the rest of the call (sync and image output).
"""

import functools
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

from .errors import PeerUnavailable

#: Blender point-light power (W) per unit of radiant intensity (W/sr) that Cycles emits:
#: Cycles treats a light's power as that of a sphere light radiating into 4 pi steradians
#: with a cosine lobe, which leaves intensity = P / (4 pi^2) for a point (checked against
#: volmc by tests/test_peer_cycles.py).
POINT_POWER_PER_INTENSITY = 4.0 * math.pi
#: Largest bounce count Cycles accepts (its "unbounded").
MAX_BOUNCES = 1024
WORKER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "cycles_worker.py")

_PROBE = "import bpy, sys; print(bpy.app.version_string)"


@functools.lru_cache(maxsize=None)
def probe():
    """Blender's version string; raises PeerUnavailable with the reason when bpy cannot
    run (it is loaded in a child process, like every Cycles render)."""
    import importlib.util
    if importlib.util.find_spec("bpy") is None:
        raise PeerUnavailable(
            "Blender's bpy module is not installed (pip install 'volmc[cycles]', which needs "
            f"Python 3.11; this is Python {sys.version_info.major}.{sys.version_info.minor})")
    try:
        out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                             timeout=300)
    except subprocess.TimeoutExpired:
        raise PeerUnavailable("importing bpy did not finish within 300 s")
    if out.returncode != 0:
        last = (out.stderr.strip().splitlines() or [f"exit status {out.returncode}"])[-1]
        raise PeerUnavailable(f"bpy does not load here ({last})")
    return out.stdout.strip().splitlines()[-1]


def _proportional(a, b, rel=1e-6):
    """Whether RGB a = k b for some k >= 0 (or b = k a): a x b = 0 with both non-negative."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return bool(np.all(np.abs(np.cross(a, b)) <= rel * max(a.max(), b.max()) ** 2))


def _phase_g(med):
    return float(med.phase.g) if med.phase.type == "hg" else 0.0


def mixes_phases_by_channel(a, b):
    """Whether volmc's mix of the phase functions of overlapping media a and b depends on the
    colour channel (their phase functions differ and their albedos are not proportional),
    which Cycles does not reproduce (see the module docstring)."""
    return _phase_g(a) != _phase_g(b) and not _proportional(a.albedo, b.albedo)


def check_translatable(scene):
    """Raise PeerUnavailable for what the translation does not carry over: blackbody
    (temperature) emission, in any medium, and overlapping media whose phase functions
    differ while their albedos are not proportional (Cycles mixes the phase functions the
    same way in every channel), environment maps (not translated yet: the world
    background is one colour), sun discs, spot and sphere lights (not translated yet)."""
    media = scene.spec.media
    for i, lt in enumerate(scene.spec.lights):
        if getattr(lt, "file", None) is not None:
            raise PeerUnavailable(f"lights[{i}] is an environment map, which the Cycles "
                                  "translation does not carry over yet (its world background "
                                  "is one colour); compare with Mitsuba 3")
        if lt.type in ("spot", "sphere") or getattr(lt, "angle", 0.0) > 0.0:
            what = "a sun disc" if lt.type == "directional" else f"a {lt.type} light"
            raise PeerUnavailable(f"lights[{i}] is {what}, which the Cycles translation does "
                                  "not carry over yet; compare with Mitsuba 3")
    if scene.spec.render.max_depth != 0:   # 0: no scattering (the albedo becomes 0)
        from .mitsuba import boxes_overlap
        for i in range(len(media)):
            for j in range(i + 1, len(media)):
                if mixes_phases_by_channel(media[i], media[j]) and \
                        boxes_overlap(media[i], media[j]):
                    raise PeerUnavailable(
                        f"media[{i}] and media[{j}] overlap with different phase functions "
                        f"and albedos that are not proportional, so the scene is not "
                        f"translatable: volmc mixes their phase functions by each channel's "
                        f"sigma_s, Cycles by one weight for all channels; make the albedos "
                        f"proportional, the phase functions equal, or the boxes apart")
    for i, med in enumerate(media):
        em = getattr(med, "emission", None)
        if em is not None and em.radiance is None:
            key = "medium" if len(media) == 1 else f"media[{i}]"
            raise PeerUnavailable(f"Cycles' Blackbody node is not volmc's blackbody radiance "
                                  f"in nits, so temperature emission ({key}.emission."
                                  f"temperature) is not translated; compare with radiance "
                                  f"emission or none")


def _floats(v):
    return [float(x) for x in v]


def _faces_zero(a):
    return not (a[0].any() or a[-1].any() or a[:, 0].any() or a[:, -1].any()
                or a[:, :, 0].any() or a[:, :, -1].any())


def _grid_entry(grid, bounds, folder, name, pad, prefix=""):
    """Write ``grid`` ([z, y, x]) for the worker: the .npy path (``prefix`` + name), the world
    position of the centre of voxel (0, 0, 0) and the voxel size, with one layer of edge
    copies when ``pad``."""
    a = np.asarray(grid, np.float32)
    lo, hi = np.asarray(bounds[0], np.float64), np.asarray(bounds[1], np.float64)
    vox = (hi - lo) / np.array(a.shape[::-1], np.float64)
    first = lo + vox / 2
    if pad:
        a = np.pad(a, 1, mode="edge")
        first = first - vox
    path = os.path.join(folder, f"{prefix}{name}.npy")
    np.save(path, np.ascontiguousarray(a))
    return {"file": path, "first_centre": _floats(first), "voxel": _floats(vox)}


def medium_job(scene, folder, prefix=""):
    """The medium part of a job for a one-medium scene (one of ``Scene.media_scenes``):
    coefficients, grids written into ``folder`` with file names starting ``prefix``."""
    med, ren = scene.spec.medium, scene.spec.render
    scale = _floats(med.scale)
    albedo = _floats(med.albedo) if ren.max_depth != 0 else [0.0, 0.0, 0.0]
    out = {"bounds": [_floats(med.bounds[0]), _floats(med.bounds[1])], "scale": scale,
           "albedo": albedo, "g": float(med.phase.g) if med.phase.type == "hg" else 0.0,
           "density": None, "grid": None, "clip_to_bounds": False, "emission": None,
           "transform": None if med.transform is None else [_floats(r) for r in med.transform]}
    grids = [("density", scene.grid)]
    em = med.emission
    if em is not None:
        # Per channel: sigma_a / density x radiance, with the scene's own albedo (the
        # emission stays when max_depth = 0 turns scattering into absorption).
        colour = [(1.0 - a) * s * r for a, s, r in zip(_floats(med.albedo), scale,
                                                          _floats(em.radiance))]
        field = np.asarray(scene.emission_grid, np.float32)
        out["emission"] = {"colour": colour, "field": None, "constant": None}
        if field.size == 1:
            out["emission"]["constant"] = float(field.reshape(-1)[0])
        else:
            grids.append(("emission", field))
    if scene.grid is None:
        out["density"] = float(med.density.value)
        if len(grids) > 1:
            # A constant density with a field: the density becomes a grid of the field's
            # shape, so both are read from one VDB file.
            grids[0] = ("density", np.full(grids[1][1].shape, out["density"], np.float32))
    if grids[0][1] is not None:
        arrays = [np.asarray(g, np.float32) for _, g in grids]
        # Each grid spans the box with its own resolution: each gets its own transform.
        pad = not all(_faces_zero(a) for a in arrays)
        out["clip_to_bounds"] = pad
        out["grid"] = {name: _grid_entry(a, med.bounds, folder, name, pad, prefix)
                       for (name, _), a in zip(grids, arrays)}
    return out


def light_jobs(scene):
    out = []
    for light in scene.spec.lights:
        if light.type == "environment":
            out.append({"type": "environment", "radiance": _floats(light.radiance)})
        elif light.type == "directional":
            out.append({"type": "directional", "direction": _floats(light.direction),
                        "irradiance": _floats(light.irradiance)})
        else:
            out.append({"type": "point", "position": _floats(light.position),
                        "power": [POINT_POWER_PER_INTENSITY * float(x)
                                  for x in light.intensity]})
    return out


def volume_bounces(max_depth):
    """Cycles' volume_bounces for volmc's max_depth (see the module docstring)."""
    return MAX_BOUNCES if max_depth < 0 else max(max_depth - 1, 0)


def write_job(scene, folder, pass_spp, pass_seeds, threads=0):
    """Write the job of rendering ``scene`` into ``folder``; returns the JSON path."""
    check_translatable(scene)
    cam = scene.spec.camera
    parts = scene.media_scenes
    job = {"folder": folder, "resolution": [int(x) for x in cam.resolution],
           "threads": int(threads),
           "camera": {"type": cam.type, "fit": "VERTICAL", "eye": _floats(cam.eye),
                      "target": _floats(cam.target), "up": _floats(cam.up),
                      "fov": float(cam.fov), "size": float(cam.size),
                      "aperture": float(cam.aperture),
                      "focus_distance": float(cam.focus_distance)},
           "medium": medium_job(parts[0], folder),
           "others": [medium_job(p, folder, f"m{i}_") for i, p in enumerate(parts[1:], 1)],
           "lights": light_jobs(scene),
           "volume_bounces": volume_bounces(scene.spec.render.max_depth),
           "transparent": bool(scene.spec.render.transparent_background),
           "pass_spp": [int(n) for n in pass_spp], "pass_seeds": [int(s) for s in pass_seeds]}
    path = os.path.join(folder, "job.json")
    with open(path, "w") as f:
        json.dump(job, f, indent=1)
    return path


def run_job(path, timeout=None):
    """Run the worker on a job; returns its npz contents as a dict."""
    out = subprocess.run([sys.executable, WORKER, path], capture_output=True, text=True,
                         timeout=timeout)
    result = os.path.splitext(path)[0] + ".npz"
    if out.returncode != 0 or not os.path.exists(result):
        last = (out.stderr.strip().splitlines() or [f"exit status {out.returncode}"])[-1]
        raise PeerUnavailable(f"the Cycles worker failed ({last})")
    with np.load(result) as z:
        return {k: z[k] for k in z.files}


class CyclesRenderer:
    """Renders a volmc scene with Cycles; ``render`` as MitsubaRenderer's, with Cycles'
    tracing time as the seconds and its sync time in ``last_sync_seconds``."""

    def __init__(self, scene, threads=0):
        check_translatable(scene)
        self.scene = scene
        self.threads = threads
        self.version = probe()
        self.folder = tempfile.mkdtemp(prefix="volmc-cycles-")
        self.last_sync_seconds = math.nan
        self.last_wall_seconds = math.nan

    mode = "Cycles CPU, null-scattering volumes"

    def close(self):
        shutil.rmtree(self.folder, ignore_errors=True)

    def __del__(self):
        self.close()

    def warm_up(self):
        """Nothing is cached between Cycles renders (each starts a worker), but the first
        import of bpy reads Blender's files from disk: one tiny render warms the page cache."""
        self._run([1], [2**31 - 1])

    def _run(self, sizes, seeds):
        import time
        t = time.perf_counter()
        result = run_job(write_job(self.scene, self.folder, sizes, seeds, self.threads))
        self.last_wall_seconds = time.perf_counter() - t
        return result

    def render(self, spp, seed=0, passes=None):
        """(mean, variance of the mean, tracing seconds, [passes, 3] pass image means).

        The image is the sample-weighted mean of ``passes`` renders (default 1) with seeds
        derived from ``seed``; the spread of the passes gives the variance of the mean (NaN
        for one pass). Tracing seconds are Cycles' own, summed over the passes;
        ``last_sync_seconds`` holds the rest of Cycles' time (scene sync, output), and
        ``last_low`` each pixel channel's least pass value (for compare.agreement)."""
        passes = max(1, min(passes or 1, spp))
        sizes = [spp // passes + (1 if i < spp % passes else 0) for i in range(passes)]
        seeds = [(seed * 100_003 + i) % (2**31 - 1) for i in range(passes)]
        r = self._run(sizes, seeds)
        stack = np.asarray(r["passes"], np.float64)
        self.last_sync_seconds = float(np.sum(r["sync"]))
        mean = np.tensordot(np.array(sizes, np.float64) / spp, stack, axes=1)
        var = (stack.var(axis=0, ddof=1) / passes if passes > 1
               else np.full_like(mean, np.nan))
        self.last_low = stack.min(axis=0)
        return mean, var, float(np.sum(r["tracing"])), stack.mean(axis=(1, 2))
