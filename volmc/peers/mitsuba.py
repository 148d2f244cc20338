"""Mitsuba 3 as a peer renderer: translate a volmc scene, render it with ``volpath``.

Conventions and how the translation matches them (each checked by tests/test_peer_mitsuba.py
or by the cross-check of docs/peers.md):

- **Camera.** volmc's ``fov`` is the full vertical angle; Mitsuba's ``perspective`` gets
  ``fov_axis = "y"`` and ``look_at(eye, target, up)``, which puts +x on the right when looking
  down -z with +y up, as volmc does. volmc's orthographic ``size`` is the vertical extent in
  world units; Mitsuba's ``orthographic`` camera spans [-1, 1] horizontally and
  [-1/aspect, 1/aspect] vertically, so its ``to_world`` gets a scale of size * aspect / 2.
  Both sample the pixel uniformly (Mitsuba: ``box`` reconstruction filter, radius half a pixel).
  A thin lens (``aperture`` > 0) becomes Mitsuba's ``thinlens`` with ``aperture_radius`` =
  aperture and the same ``focus_distance``: both sample the lens disc uniformly and focus
  on the plane at that distance along the view axis. Mitsuba's rays start at ``near_clip``
  along the view axis (default 0.01), volmc's at the eye: ``near_clip`` is set far below a
  voxel (NEAR_CLIP), or a camera inside a medium would skip its first centimetre.
  Mitsuba has no orthographic thin lens
  and no equirectangular sensor, so an orthographic camera with an aperture and a
  panoramic camera raise PeerUnavailable, as does a lens reaching across the medium box's
  surface (the sensor's medium is one for all its rays).
- **Medium box.** A ``cube`` shape ([-1, 1]^3) scaled to ``medium.bounds`` with a ``null`` BSDF
  carries the medium as its interior. A camera inside the box gets the medium as its
  exterior medium (Mitsuba needs to be told; volmc finds it by geometry).
- **Several media** (``[[media]]``): one cube per medium, each with its own interior medium
  (``volmc_medium``/``box`` for the first, ``volmc_medium1``/``box1`` ... for the others),
  as long as no two placed boxes overlap. volmc adds the coefficients of overlapping media;
  Mitsuba's ``volpath`` keeps one current medium per ray (the interior of the last box
  entered), so it cannot, and a scene whose boxes overlap or touch is refused
  (PeerUnavailable), decided exactly by separating axes of the two placed boxes
  (parallelepipeds). A lens must then be clear of every box's surface.
- **Placement.** ``medium.transform`` (world = M x local, distances in world units on both
  sides) is the ``to_world`` of the grid and of the cube, before their own placement in the
  box; a mirroring M is taken off the cube (a symmetric shape) so its faces stay outward.
- **Transparent background.** ``render.transparent_background`` is the integrator's
  ``hide_emitters``: emitters seen directly by camera rays (through the medium's null
  collisions too) are hidden, the lighting stays.
- **Grid.** Both index arrays [z, y, x] with x fastest, put voxel centres at
  (i + 0.5) / n of the box, interpolate trilinearly and clamp to the edge voxels
  (Mitsuba's ``gridvolume`` with its default ``filter_type = "bilinear"``, ``wrap_mode =
  "clamp"``). Its ``to_world`` maps the unit cube to ``medium.bounds``. Extinction is
  ``scale * density`` on both sides (``heterogeneous.scale``).
- **Colour-dependent extinction.** ``medium.scale`` is an RGB triple (a float, for a grey
  medium, counts as three equal values); extinction in channel c is scale[c] * density.
  A grey medium is translated as above. A chromatic one gets ``sigma_t`` as an RGB value
  (``srgb`` with ``unbounded``: the ``rgb`` type refuses values above 1) when homogeneous,
  and as a 3-channel ``gridvolume`` holding scale[c] * density, with ``heterogeneous.scale``
  1, when a grid; Mitsuba's majorant is then the largest value of any channel, and its
  integrators pick one channel per path and weight the others. ``volpathmis`` (spectral MIS)
  renders it: with ``volpath`` a homogeneous chromatic medium's weights exp((s_hero - s_c) t)
  are unbounded. Checked against exp(-scale[c] * density * d) through an absorbing slab. For
  the comparison with volmc, MitsubaRenderer renders a chromatic scene as one grey scene per
  distinct scale value instead (``split_scenes``): exact, and far less noisy.
  (``volpath`` before Mitsuba 3.7 chose null against real collisions by the hero channel
  alone, biased wherever that channel's extinction reaches the majorant: mitsuba3 issue
  #1387, fixed by #1628. ``volpathmis`` and the grey scenes are unaffected.)
- **Lights.** ``environment`` becomes ``constant`` (radiance), or with a map ``envmap``
  (the same file's radiance, resampled at Mitsuba's texel centres on a finer grid, since
  Mitsuba interpolates bilinearly: ENVMAP_WIDTH; the rotation as to_world);
  ``directional`` stays
  ``directional`` (irradiance, direction of travel), ``point`` becomes ``point`` (intensity),
  ``spot`` becomes ``spot`` (intensity on the axis, ``cutoff_angle`` = ``beam_width`` =
  angle, a look-at to_world along its direction: only blend = 0, since Mitsuba's falloff is
  linear in angle), ``sphere`` a ``sphere`` shape with an ``area`` emitter of its radiance
  and a black ``diffuse`` BSDF (opaque, reflecting nothing). Not translated: a sun disc
  (``angle`` > 0; Mitsuba's directional light is parallel), a camera inside a sphere light
  (Mitsuba's area emitter is one-sided), a sphere light with a transparent background
  (``hide_emitters`` would hide it).
  The units agree: an empty scene shows the environment radiance in both.
- **Phase.** Both use Henyey-Greenstein with g > 0 scattering forward.
- **Path depth.** volmc's ``max_depth`` counts scattering events; Mitsuba's counts path
  vertices including the camera ray's end, so Mitsuba gets max_depth + 1 (and rr_depth + 1);
  -1 (unbounded) stays -1.
- **Colour.** Mitsuba's ``llvm_ad_rgb`` variant: RGB throughout, as in volmc.
- **Not translated.** An emissive medium (``medium.emission``): Mitsuba 3's media do not
  emit, so such a scene raises PeerUnavailable instead of being compared without it. So do
  overlapping media (above).

Mitsuba is optional (``pip install 'volmc[peers]'``). Its LLVM backend needs a libLLVM it
can load; ``DRJIT_LIBLLVM_PATH`` names one, otherwise the newest ``libLLVM.so.1x`` in the
usual library directories is used. Loading is first tried in a subprocess, because a
libLLVM that Dr.Jit cannot use crashes the interpreter instead of raising.
"""

import functools
import glob
import math
import os
import subprocess
import sys
import time

import numpy as np

from .errors import PeerUnavailable

VARIANT = "llvm_ad_rgb"
#: Largest number of camera rays per Mitsuba launch (memory: Dr.Jit keeps per-lane state).
MAX_LANES = 1 << 22
_LIB_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64",
             "/usr/lib", "/usr/local/lib", "/opt/homebrew/opt/llvm/lib")


def find_libllvm():
    """Path of a libLLVM for Dr.Jit: $DRJIT_LIBLLVM_PATH, else the newest found, else None."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env:
        return env
    found = []
    for d in _LIB_DIRS:
        found += glob.glob(os.path.join(d, "libLLVM.so.1[0-9]*"))
        found += glob.glob(os.path.join(d, "libLLVM-1[0-9]*.so*"))
    def version(p):
        digits = "".join(c if c.isdigit() or c == "." else " " for c in os.path.basename(p))
        nums = [int(x) for x in digits.replace(".", " ").split() if x]
        return nums[:2]
    return max(found, key=version) if found else None


_PROBE = ("import mitsuba as mi; mi.set_variant('{v}'); "
          "s = mi.load_dict({{'type': 'scene', 'e': {{'type': 'constant'}}, "
          "'i': {{'type': 'path'}}, "
          "'sensor': {{'type': 'perspective', 'film': {{'type': 'hdrfilm', 'width': 2, "
          "'height': 2}}}}}}); mi.render(s, spp=1); print(mi.__version__)")


@functools.lru_cache(maxsize=None)
def probe():
    """Mitsuba's version string; raises PeerUnavailable with the reason when it cannot run."""
    try:
        import mitsuba  # noqa: F401  (only whether it is installed; loading happens below)
    except ImportError:
        raise PeerUnavailable("Mitsuba 3 is not installed (pip install 'volmc[peers]')")
    env = dict(os.environ)
    lib = find_libllvm()
    if lib:
        env["DRJIT_LIBLLVM_PATH"] = lib
    try:
        out = subprocess.run([sys.executable, "-c", _PROBE.format(v=VARIANT)], env=env,
                             capture_output=True, text=True, timeout=300)
    except subprocess.TimeoutExpired:
        raise PeerUnavailable("Mitsuba's test render did not finish within 300 s")
    if out.returncode != 0:
        last = (out.stderr.strip().splitlines() or [f"exit status {out.returncode}"])[-1]
        raise PeerUnavailable(
            f"Mitsuba's {VARIANT} variant does not run here ({last}); install a libLLVM it "
            f"can load (e.g. apt-get install libllvm19) and set DRJIT_LIBLLVM_PATH "
            f"(tried {lib or 'no libLLVM found'})")
    if lib:
        os.environ["DRJIT_LIBLLVM_PATH"] = lib
    return out.stdout.strip().splitlines()[-1]


def _mi():
    probe()
    import mitsuba as mi
    mi.set_variant(VARIANT)
    return mi


def _rgb(v):
    return {"type": "rgb", "value": [float(x) for x in v]}


def medium_scale(med):
    """``medium.scale`` as an RGB triple of floats: a float s (a grey medium) gives (s, s, s)."""
    s = med.scale
    return tuple(float(x) for x in s) if isinstance(s, (tuple, list)) else (float(s),) * 3


def _inside(p, medium):
    """True when world point p is inside the (placed) medium box."""
    if medium.transform is not None:
        m = np.asarray(medium.transform, float)
        p = np.linalg.solve(m[:3, :3], np.asarray(p, float) - m[:3, 3])
    return all(medium.bounds[0][i] < p[i] < medium.bounds[1][i] for i in range(3))


def _lens_straddles(cam, medium):
    """Whether points within ``aperture`` of the eye lie on both sides of the (placed) box's
    surface (a ball about the eye: conservative for the lens disc; in the medium's own space
    the ball grows by the inverse transform's largest stretch)."""
    lo, hi = medium.bounds
    eye, radius = np.asarray(cam.eye, float), cam.aperture
    if medium.transform is not None:
        m = np.asarray(medium.transform, float)
        inv = np.linalg.inv(m[:3, :3])
        eye, radius = inv @ (eye - m[:3, 3]), radius * float(np.linalg.norm(inv, 2))
    gap = math.sqrt(sum(max(lo[i] - eye[i], 0.0, eye[i] - hi[i]) ** 2 for i in range(3)))
    depth = min(min(eye[i] - lo[i], hi[i] - eye[i]) for i in range(3))
    return (gap if gap > 0.0 else depth) < radius


def _film_straddles(cam, medium):
    """Whether an orthographic camera's film (where its rays start: a rectangle ``size``
    high and ``size`` x width / height wide, centred on the eye and facing the target)
    has points on both sides of the (placed) box's surface: it meets the box (touching
    counts) without lying wholly inside it."""
    from types import SimpleNamespace
    from ..pack import camera_basis
    w, h = cam.resolution
    eye = np.asarray(cam.eye, float)
    f, r, v = (np.asarray(x, float) for x in camera_basis(cam))
    hw, hh = cam.size * w / h / 2.0, cam.size / 2.0
    corners = [eye + a * hw * r + b * hh * v for a in (-1, 1) for b in (-1, 1)]
    if all(_inside(c, medium) for c in corners):   # the box is convex
        return False
    place = np.eye(4)
    place[:3, :3] = np.column_stack([r, v, f])
    place[:3, 3] = eye
    film = SimpleNamespace(bounds=((-hw, -hh, 0.0), (hw, hh, 0.0)), transform=place)
    return boxes_overlap(film, medium)


def _box_corners(medium):
    """(8 x 3 world corners, 3 x 3 world edge directions as rows) of the placed box."""
    lo, hi = medium.bounds
    c = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                  for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
    if medium.transform is None:
        return c, np.eye(3)
    m = np.asarray(medium.transform, float)
    return c @ m[:3, :3].T + m[:3, 3], m[:3, :3].T.copy()


def boxes_overlap(a, b):
    """Whether the placed boxes of media a and b overlap or touch (separating axes: the
    affine images of two boxes are parallelepipeds, separated exactly when their corners'
    projections on some face normal of either, or on the cross product of an edge of each,
    are apart). A gap below 1e-9 of the projections' span counts as touching."""
    ca, ea = _box_corners(a)
    cb, eb = _box_corners(b)
    ea = ea / np.linalg.norm(ea, axis=1, keepdims=True)
    eb = eb / np.linalg.norm(eb, axis=1, keepdims=True)
    axes = [np.cross(e[(i + 1) % 3], e[(i + 2) % 3]) for e in (ea, eb) for i in range(3)]
    axes += [np.cross(x, y) for x in ea for y in eb]
    for n in axes:
        length = np.linalg.norm(n)
        if length < 1e-9:   # parallel edges: the face normals cover this direction
            continue
        pa, pb = ca @ (n / length), cb @ (n / length)
        tol = 1e-9 * (max(pa.max(), pb.max()) - min(pa.min(), pb.min()))
        if pa.max() < pb.min() - tol or pb.max() < pa.min() - tol:
            return False
    return True


def caveats(scene):
    """What Mitsuba 3 renders wrongly in a scene it translates, one note each, for the
    report beside its verdict: a sphere light close outside a medium's box
    (_sphere_hugs_box), whose light Mitsuba loses there."""
    media = scene.spec.media
    notes = []
    for i, light in enumerate(scene.spec.lights):
        for j, med in enumerate(media):
            if light.type == "sphere" and _sphere_hugs_box(light, med):
                box = "medium box" if len(media) == 1 else f"media[{j}] box"
                notes.append(f"lights[{i}] (a sphere) is close outside the {box}, where "
                             f"Mitsuba 3's volume integrators lose some of its light (a "
                             f"shadow ray restarted at the box's surface ends inside the "
                             f"sphere; docs/peers.md): Mitsuba may come out darker there")
    return notes


#: How close outside a medium's box a sphere light is noted (caveats), in units of 1 plus
#: the scene's largest coordinate (the scale of Mitsuba's ray offsets; see _sphere_hugs_box).
SPHERE_GAP = 0.25


def _sphere_hugs_box(light, medium):
    """Whether sphere light ``light``, centred outside the placed box of ``medium``, comes
    within SPHERE_GAP (1 + the largest coordinate) of it. Mitsuba 3's volpath (3.9.1) restarts
    a shadow ray at each null interface offset along the normal by about 1e-4 (1 + |p|) but
    keeps the length of the ray it cut, so the ray ends up to that far past its aim, while it
    stops short of the light by only about 9e-4 of its length: within a few tenths of a unit
    the ray ends inside the sphere and counts as blocked (a sphere of radius 0.5 touching a
    unit box rendered up to 25 % dark beside it, 1.3 % over the image; a gap of 0.1 still
    showed it, a gap of 1 did not). The box is bounded by its corners' world AABB, which is
    never farther than the box."""
    corners, _ = _box_corners(medium)
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    c = np.asarray(light.position, float)
    if np.all((c >= lo) & (c <= hi)):
        return False   # inside (or on) the box: no interface between it and the medium
    gap = float(np.linalg.norm(c - np.clip(c, lo, hi))) - light.radius
    scale = 1.0 + max(float(np.abs(corners).max()), float(np.abs(c).max()) + light.radius)
    return gap < SPHERE_GAP * scale


def _key(scene, i, key):
    """A medium's key as the scene file names it: ``medium.<key>``, or ``media[i].<key>``."""
    return f"medium.{key}" if len(scene.spec.media) == 1 else f"media[{i}].{key}"


def check_translatable(scene):
    """Raise PeerUnavailable when the scene has what Mitsuba 3 cannot render: an emissive
    medium (its media have no emission; neither ``volpath`` nor ``volpathmis`` adds any), a
    panoramic camera (no equirectangular sensor), an orthographic thin lens, a lens or an
    orthographic film reaching across a medium box's surface (the sensor has one medium for
    all its rays, while volmc starts each ray in the medium its start is in), or media whose
    placed boxes overlap or touch (volmc adds overlapping media's coefficients; Mitsuba's
    ``volpath`` has one medium at a time)."""
    media = scene.spec.media
    for i, med in enumerate(media):
        if getattr(med, "emission", None) is not None:
            raise PeerUnavailable(f"Mitsuba 3 has no emissive media, so it cannot render "
                                  f"{_key(scene, i, 'emission')}; compare without it")
    cam = scene.spec.camera
    if cam.type == "panoramic":
        raise PeerUnavailable("Mitsuba 3 has no equirectangular sensor, so it cannot render "
                              "camera.type = \"panoramic\"")
    if cam.type == "orthographic" and cam.aperture > 0.0:
        raise PeerUnavailable("Mitsuba 3's thin lens is perspective only, so it cannot render "
                              "an orthographic camera with camera.aperture > 0")
    for i, med in enumerate(media):
        box = "medium box's" if len(media) == 1 else f"media[{i}] box's"
        if cam.aperture > 0.0 and _lens_straddles(cam, med):
            raise PeerUnavailable(f"the lens reaches across the {box} surface, and a "
                                  "Mitsuba 3 sensor has one medium for all its rays; move the "
                                  "camera or narrow camera.aperture")
        if cam.type == "orthographic" and _film_straddles(cam, med):
            raise PeerUnavailable(f"the orthographic camera's film reaches across the {box} "
                                  "surface, and a Mitsuba 3 sensor has one medium for all "
                                  "its rays; move the camera or shrink camera.size")
    for i, light in enumerate(scene.spec.lights):
        if light.type == "directional" and light.angle > 0.0:
            raise PeerUnavailable(f"Mitsuba 3's directional light is parallel, so it cannot "
                                  f"render lights[{i}].angle > 0 (a sun disc)")
        if light.type == "spot" and light.blend > 0.0:
            raise PeerUnavailable(f"Mitsuba 3's spot falls off linearly in angle, not by "
                                  f"volmc's smoothstep, so it cannot render lights[{i}].blend "
                                  f"> 0; compare with blend = 0")
        if light.type == "sphere":
            if cam.type != "orthographic" and math.dist(cam.eye, light.position) <= \
                    light.radius:
                raise PeerUnavailable(f"the camera is inside lights[{i}] (a sphere), whose "
                                      "inside Mitsuba 3's one-sided area emitter leaves dark")
            if scene.spec.render.transparent_background:
                raise PeerUnavailable(f"Mitsuba 3's hide_emitters would hide lights[{i}] (a "
                                      "sphere) from the camera, which volmc shows as an object "
                                      "in front of a transparent background")

    for i in range(len(media)):
        for j in range(i + 1, len(media)):
            if boxes_overlap(media[i], media[j]):
                raise PeerUnavailable(
                    f"media[{i}] and media[{j}] overlap (or touch), so the scene is not "
                    f"translatable: volmc adds the coefficients of overlapping media, while "
                    f"Mitsuba 3's volpath has one medium at a time (the interior of the box "
                    f"last entered); move their boxes apart")


def _medium_dict(mi, med, grid, grey):
    """(Mitsuba medium dictionary, the cube's to_world) of one placed medium."""
    from ..scene.schema import ConstantDensity
    T = mi.ScalarTransform4f
    (x0, y0, z0), (x1, y1, z1) = med.bounds
    ext = (x1 - x0, y1 - y0, z1 - z0)   # > 0 on every axis: scene validation ensures it
    # medium.transform places the box: Mitsuba's to_world of the grid and of the cube, both
    # world = M x local (distances are world distances on both sides). A mirror flips the
    # cube's faces inside out, so the cube (symmetric) takes the mirror off its own axes.
    place = T(np.asarray(med.transform, float).tolist()) if med.transform is not None else T()
    unmirror = T().scale([-1.0, 1.0, 1.0]) if (
        med.transform is not None and np.linalg.det(np.asarray(med.transform)[:3, :3]) < 0) \
        else T()

    phase = ({"type": "hg", "g": float(med.phase.g)} if med.phase.type == "hg"
             else {"type": "isotropic"})
    scale = medium_scale(med)
    if isinstance(med.density, ConstantDensity):
        sigma_t = [s * med.density.value for s in scale]
        medium = {"type": "homogeneous", "albedo": _rgb(med.albedo), "phase": phase,
                  # "rgb" refuses values above 1 (a reflectance); "srgb" with "unbounded"
                  # takes any non-negative colour as it is.
                  "sigma_t": (float(sigma_t[0]) if grey else
                              {"type": "srgb", "color": sigma_t, "unbounded": True})}
    else:
        grid = np.asarray(grid, np.float32)
        if grey:
            data, mscale = grid[..., None], scale[0]
        else:
            # One channel per colour: the extinction scale[c] * density baked into the grid
            # (float32 products, as volmc forms them), heterogeneous.scale left at 1.
            data, mscale = grid[..., None] * np.asarray(scale, np.float32), 1.0
        medium = {"type": "heterogeneous", "scale": float(mscale), "phase": phase,
                  "sigma_t": {"type": "gridvolume",
                              "grid": mi.VolumeGrid(np.ascontiguousarray(data, np.float32)),
                              "to_world": place @ T().translate([x0, y0, z0])
                              .scale(list(ext))},
                  "albedo": {"type": "constvolume", "value": _rgb(med.albedo)}}
    to_world = place @ T().translate([(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2]) \
        .scale([e / 2 for e in ext]) @ unmirror
    return medium, to_world


def medium_ids(i):
    """(medium id, cube key) of medium i in the Mitsuba scene dictionary."""
    return ("volmc_medium", "box") if i == 0 else (f"volmc_medium{i}", f"box{i}")


def _grey(scene):
    return all(len(set(medium_scale(p.spec.medium))) == 1 for p in scene.media_scenes)


#: Mitsuba's near clip distance, in units of the distance from the eye to the target (at least
#: 1): far below a voxel, far above float32's resolution of the eye's position.
NEAR_CLIP = 1e-5


def scene_dict(scene, mi=None):
    """The Mitsuba 3 scene dictionary of a volmc Scene (see the module docstring).

    Raises PeerUnavailable for a scene Mitsuba cannot render (see check_translatable)."""
    check_translatable(scene)
    mi = mi or _mi()
    T = mi.ScalarTransform4f
    spec = scene.spec
    cam, ren = spec.camera, spec.render
    grey = _grey(scene)

    w, h = cam.resolution
    look = T().look_at(origin=list(cam.eye), target=list(cam.target), up=list(cam.up))
    if cam.type == "perspective" and cam.aperture > 0.0:
        sensor = {"type": "thinlens", "fov": float(cam.fov), "fov_axis": "y", "to_world": look,
                  "aperture_radius": float(cam.aperture),
                  "focus_distance": float(cam.focus_distance)}
    elif cam.type == "perspective":
        sensor = {"type": "perspective", "fov": float(cam.fov), "fov_axis": "y",
                  "to_world": look}
    else:
        s = cam.size * (w / h) / 2.0
        sensor = {"type": "orthographic", "to_world": look @ T().scale([s, s, 1.0])}
    # Mitsuba's cameras start their rays at near_clip (default 0.01) along the view axis: the
    # medium of a camera inside it would lose its first centimetre. volmc's rays start at
    # the eye (the lens).
    sensor["near_clip"] = NEAR_CLIP * max(1.0, math.dist(cam.eye, cam.target))
    sensor["film"] = {"type": "hdrfilm", "width": int(w), "height": int(h),
                      "rfilter": {"type": "box"}, "pixel_format": "rgb"}
    sensor["sampler"] = {"type": "independent", "sample_count": int(ren.spp)}

    depth = -1 if ren.max_depth < 0 else ren.max_depth + 1
    d = {"type": "scene",
         "integrator": {"type": "volpath" if grey else "volpathmis", "max_depth": int(depth),
                        "hide_emitters": bool(ren.transparent_background),
                        "rr_depth": int(ren.rr_depth + 1)},
         "sensor": sensor}
    for i, part in enumerate(scene.media_scenes):
        med = part.spec.medium
        mid, box = medium_ids(i)
        medium, to_world = _medium_dict(mi, med, part.grid, grey)
        medium["id"] = mid
        d[mid] = medium
        d[box] = {"type": "cube", "bsdf": {"type": "null"},
                  "interior": {"type": "ref", "id": mid}, "to_world": to_world}
        # The boxes do not overlap (check_translatable): the eye is in at most one.
        if _inside(cam.eye, med):
            sensor["medium"] = {"type": "ref", "id": mid}
    for i, light in enumerate(spec.lights):
        if light.type == "environment" and light.file is not None:
            d[f"light{i}"] = _envmap_dict(mi, spec, i, light)
        elif light.type == "environment":
            d[f"light{i}"] = {"type": "constant", "radiance": _rgb(light.radiance)}
        elif light.type == "directional":
            d[f"light{i}"] = {"type": "directional", "direction": [float(x) for x in
                                                                   light.direction],
                              "irradiance": _rgb(light.irradiance)}
        elif light.type == "spot":
            pos = [float(x) for x in light.position]
            ax = np.asarray(light.direction, float)
            up = [0.0, 1.0, 0.0] if abs(ax[1]) < 0.9 else [1.0, 0.0, 0.0]
            # blend 0 (checked above): the full intensity out to the cut-off, as volmc's
            d[f"light{i}"] = {"type": "spot", "intensity": _rgb(light.intensity),
                              "cutoff_angle": float(light.angle),
                              "beam_width": float(light.angle),
                              "to_world": T().look_at(origin=pos,
                                                      target=(np.asarray(pos) + ax).tolist(),
                                                      up=up)}
        elif light.type == "sphere":
            d[f"light{i}"] = {"type": "sphere", "center": [float(x) for x in light.position],
                              "radius": float(light.radius),
                              "bsdf": {"type": "diffuse", "reflectance": 0.0},
                              "emitter": {"type": "area", "radiance": _rgb(light.radiance)}}
        else:
            d[f"light{i}"] = {"type": "point", "position": [float(x) for x in light.position],
                              "intensity": _rgb(light.intensity)}
    return d


#: Mitsuba's copy of an environment map is about ENVMAP_WIDTH texels wide (a whole multiple k
#: of the map's width, at least 1), with k times its rows. Mitsuba's envmap interpolates
#: bilinearly between texel centres placed at u = (i + 1/2) / W and v = j / (H - 1) (its
#: first and last rows sit on the poles); volmc's map is piecewise constant over texels
#: [i / W, (i + 1) / W] x [j / H, (j + 1) / H]. The copy holds volmc's radiance at Mitsuba's
#: texel centres, so the two differ only in bands of 1 / k of a texel along volmc's texel
#: edges, where Mitsuba blends (and, across rows, not quite symmetrically about the edge).
#: Pixels that see a map directly average it over their footprint, with almost no noise, so
#: the bands show: at k = 2 (1024 texels for the 512-wide sunrise.exr) 2.5 % of such pixel
#: channels differed significantly (by 0.2-0.5 %) in a random scene of the sweep
#: (volmc/bench/sweep.py), at k = 8 none. The copy costs 0.6 s more to load at 4096.
ENVMAP_WIDTH = 4096


def _envmap_dict(mi, spec, i, light):
    """Mitsuba's ``envmap`` of an environment map light: the same convention (volmc uses
    Mitsuba's), the texels times radiance x strength as its bitmap, and the rotation as its
    to_world."""
    import numpy as np
    from ..scene.envmap import light_texels
    px = light_texels(light, spec.file, i)
    px = px * (np.asarray(light.radiance, np.float32) * np.float32(light.strength))
    h, w = px.shape[:2]
    k = max(1, ENVMAP_WIDTH // w)
    hk, wk = h * k, w * k
    rows = np.minimum((np.arange(hk) / (hk - 1) * h).astype(int), h - 1)
    cols = np.minimum(((np.arange(wk) + 0.5) / wk * w).astype(int), w - 1)
    px = np.ascontiguousarray(px[rows][:, cols], np.float32)
    m = np.eye(4)
    if light.rotation is not None:
        m[:3, :3] = np.asarray(light.rotation, float)
    return {"type": "envmap", "bitmap": mi.Bitmap(px),
            "to_world": mi.ScalarTransform4f(m.tolist())}


def with_media(scene, media):
    """The scene with its media replaced by ``media`` (as many, in order), grids kept."""
    from dataclasses import replace
    from ..scene import Scene
    parts = scene.media_scenes
    if len(parts) == 1:
        return Scene(replace(scene.spec, medium=media[0]), scene.grid, scene.emission_grid)
    new = tuple(Scene(replace(p.spec, medium=m), p.grid, p.emission_grid)
                for p, m in zip(parts, media))
    return Scene(replace(scene.spec, medium=media[0], others=tuple(media[1:])), new[0].grid,
                 new[0].emission_grid, parts=new)


def split_scenes(scene):
    """[(grey scene, channels)]: the scene once per distinct value of its RGB scale (of the
    tuple of every medium's scale in that channel, for several media), with that value on
    every channel, and the channels that take it.

    Light transport in channel c involves only channel c's extinction, albedo and light, so
    channel c of the grey scene of scale[c] is channel c of the chromatic scene. Mitsuba's
    own chromatic estimator (one hero channel samples the path, the others are weighted by
    extinction ratios) is unbiased but heavy-tailed in the thinner channels; on the
    chromatic test scene of tests/test_peer_mitsuba.py its blue channel is about 10^4 times
    less efficient than a grey render, far too noisy for a per-pixel test."""
    from dataclasses import replace
    media = [p.spec.medium for p in scene.media_scenes]
    scales = [medium_scale(m) for m in media]
    keys = [tuple(s[c] for s in scales) for c in range(3)]
    out = []
    for key in dict.fromkeys(keys):   # distinct values, in channel order
        grey = [replace(m, scale=(s, s, s)) for m, s in zip(media, key)]
        out.append((with_media(scene, grey), tuple(c for c in range(3) if keys[c] == key)))
    return out


class MitsubaRenderer:
    """A volmc scene loaded into Mitsuba 3, rendered in passes of independent seeds.

    ``render(spp, seed)`` returns (mean image [h, w, 3] float64, per-pixel variance of the
    mean, wall seconds). The variance comes from the spread of the passes (``passes`` of
    them, each spp / passes samples per pixel), because Mitsuba's films keep only means."""

    def __init__(self, scene, split_channels=None):
        self.mi = _mi()
        self.scene = scene
        chromatic = not _grey(scene)
        #: True: each channel comes from a grey Mitsuba scene of that channel's extinction
        #: (the default for a chromatic medium; see split_scenes).
        self.split = chromatic if split_channels is None else bool(split_channels) and chromatic
        t = time.perf_counter()
        parts = split_scenes(scene) if self.split else [(scene, (0, 1, 2))]
        self.mi_scenes = [(self.mi.load_dict(scene_dict(sc, self.mi)), list(channels))
                          for sc, channels in parts]
        self.load_seconds = time.perf_counter() - t
        w, h = scene.spec.camera.resolution
        self.pixels = w * h

    @property
    def mode(self):
        """How the image is rendered, for reports."""
        n = len(self.scene.spec.media)
        boxes = "" if n == 1 else f", {n} media boxes"
        if self.split:
            return (f"volpath on {len(self.mi_scenes)} grey scenes, one per extinction "
                    f"scale{boxes}")
        return ("volpath" if _grey(self.scene) else "volpathmis") + boxes

    def warm_up(self):
        """Compile the megakernel once (Dr.Jit caches it), so timings exclude compilation."""
        self._pass(1, 2**31 - 1)

    def _pass(self, spp, seed):
        img = None
        for mi_scene, channels in self.mi_scenes:
            one = self.mi.render(mi_scene, seed=int(seed) % (2**31 - 1), spp=int(spp))
            one = np.asarray(one, np.float64)[..., :3]
            img = one if img is None else img
            img[..., channels] = one[..., channels]
        return img

    def render(self, spp, seed=0, passes=None):
        """(mean, variance of the mean, wall seconds, [passes, 3] pass image means).

        The image is the sample-weighted mean of ``passes`` launches with independent seeds
        (default: as few as memory allows). The spread of the nearly equal-size passes
        estimates the variance of one pass's mean; the overall mean's variance is that over
        the number of passes (NaN for a single pass). ``last_low`` holds each pixel
        channel's least pass value (for compare.agreement)."""
        if passes is None:
            passes = max(1, math.ceil(spp * self.pixels / MAX_LANES))
        passes = max(1, min(passes, spp))
        sizes = [spp // passes + (1 if i < spp % passes else 0) for i in range(passes)]
        t = time.perf_counter()
        stack = np.stack([self._pass(n, seed * 100_003 + i) for i, n in enumerate(sizes)])
        seconds = time.perf_counter() - t
        mean = np.tensordot(np.array(sizes, np.float64) / spp, stack, axes=1)
        var = (stack.var(axis=0, ddof=1) / passes if passes > 1
               else np.full_like(mean, np.nan))
        self.last_low = stack.min(axis=0)
        return mean, var, seconds, stack.mean(axis=(1, 2))
