"""Pack a Scene into the records and arrays every backend consumes: the parameter record,
the light array, the medium record, the density grid and the majorant grid."""

import math
from collections import namedtuple

import numpy as np

from .constants import (CAMERA_ORTHOGRAPHIC, CAMERA_PANORAMIC, CAMERA_PERSPECTIVE,
                        DENSITY_BRICKS, DENSITY_CONSTANT, DENSITY_GRID, EMISSION_NONE,
                        ENV_SAMPLING_IMPORTANCE, ENV_SAMPLING_UNIFORM,
                        EMISSION_RADIANCE, EMISSION_SAMPLING_LIGHT, EMISSION_SAMPLING_MIS,
                        EMISSION_TEMPERATURE, LIGHT_DIRECTIONAL, LIGHT_POINT,
                        LIGHT_SPHERE, LIGHT_SPOT,
                        MAJORANT_GLOBAL, MAJORANT_GRID, MAJORANT_OCTREE,
                        MIS_BALANCE, MIS_POWER, PHASE_HG, PHASE_ISOTROPIC, RR_ALBEDO,
                        RR_THROUGHPUT, SAMPLER_INDEPENDENT, SAMPLER_SOBOL, SAMPLER_STRATIFIED,
                        SPECTRAL_CHANNEL, SPECTRAL_GREY, SPECTRAL_HERO, SPECTRAL_TRACKING)
from .params import light_dtype, medium_dtype, params_dtype
from .techniques import ESTIMATORS
from .scene.schema import (FLOAT32_MAX, DirectionalLight, EnvironmentLight, PointLight,
                           SphereLight, SpotLight, chroma)
from .scene.errors import SceneError
from .scene.transform import box_frame, placement
from .scene.envmap import light_texels
from .reference.environment import environment_distribution, no_env

#: The smallest normal float32 (kernels may flush denormals to zero).
FLOAT32_MIN_NORMAL = 2.0 ** -126
#: The largest aperture / focus_distance packed: the pinhole direction's share of a lens
#: ray is then below float32's precision, and the ray's components stay far from overflow.
LENS_SLOPE_MAX = 1e30

def pack_majorant(scene, real=np.float64, grid=None):
    """(maxima, minima): per-cell density bounds [cz, cy, cx] of the majorant grid when the
    scene has a density grid and render.majorant = "grid", else 1x1x1 placeholders (the
    global bounds travel in the medium record). ``grid``: the scene's grid as stored
    (``density_storage``; default: looked up)."""
    from .reference.majorant import auto_resolution, build_majorant_grid
    from .reference.sparse_grid import majorant_from_bricks
    from .scene.bricks import BrickGrid, density_storage
    if scene.grid is None or scene.render.majorant != "grid":
        return np.zeros((1, 1, 1), real), np.zeros((1, 1, 1), real)
    grid = density_storage(scene) if grid is None else grid
    res = scene.render.majorant_resolution
    res = tuple(reversed(res)) if res else auto_resolution(grid.shape)
    if isinstance(grid, BrickGrid):
        mx, mn = majorant_from_bricks(grid.table, grid.pool, grid.dims, res)
    else:
        mx, mn = build_majorant_grid(grid, res)
    return np.ascontiguousarray(mx, real), np.ascontiguousarray(mn, real)


def pack_octree(scene, real=np.float64, grid=None):
    """(maxima, minima, children, depth) of the octree of majorants (reference/octree.py)
    when the scene has a density grid and render.majorant = "octree": per-node density
    bounds [1, 1, n_nodes], int32 first-child indices [n_nodes] and the depth; else
    placeholders and depth 0. ``grid``: the scene's grid as stored (default: looked up)."""
    from .reference.majorant import build_majorant_grid
    from .reference.octree import build_octree, octree_depth
    from .reference.sparse_grid import majorant_from_bricks
    from .scene.bricks import BrickGrid, density_storage
    if scene.grid is None or scene.render.majorant != "octree":
        return np.zeros((1, 1, 1), real), np.zeros((1, 1, 1), real), np.zeros(1, np.int32), 0
    grid = density_storage(scene) if grid is None else grid
    depth = octree_depth(grid.shape)
    res = (2 ** depth,) * 3
    if isinstance(grid, BrickGrid):
        fmx, fmn = majorant_from_bricks(grid.table, grid.pool, grid.dims, res)
    else:
        fmx, fmn = build_majorant_grid(grid, res)
    lo, hi = scene.medium.bounds
    diag = np.subtract(hi, lo)
    if scene.medium.transform is not None:   # the octree splits by the world's diagonal
        diag = np.asarray(scene.medium.transform)[:3, :3] @ diag
    mx, mn, children = build_octree(fmx, fmn, diag, max(scene.medium.scale))
    return (np.ascontiguousarray(mx.reshape(1, 1, -1), real),
            np.ascontiguousarray(mn.reshape(1, 1, -1), real), children, depth)


def _normalize(v):
    n = math.sqrt(sum(x * x for x in v))
    return tuple(x / n for x in v)


def camera_basis(camera):
    """(forward, right, up) unit vectors of a camera. +x of the image is ``right``."""
    f = _normalize([camera.target[i] - camera.eye[i] for i in range(3)])
    u0 = camera.up
    r = _normalize((f[1] * u0[2] - f[2] * u0[1], f[2] * u0[0] - f[0] * u0[2],
                    f[0] * u0[1] - f[1] * u0[0]))
    u = (r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0])
    return f, r, u


def scene_frame(scene):
    """Guard "scene frame" (robustness case 11, 12): the frame every backend renders in.

    Returns (centre, unit): the centre of the medium box and a power of two close to its
    largest half-extent. Positions are packed as (x - centre) / unit (in float64, before any
    float32 rounding), extinction as scale * unit, point-light intensities as I / unit^2;
    directions, radiances and irradiances are unchanged. Radiance along every ray is the same
    in both frames, so the image is too, but the kernels' float32 then always sees a box of
    half-size in [0.7, 1.4] at the origin: a scene translated 1e7 units away (where float32
    has an ulp of 1) or scaled by 1e-4 or 1e4 renders from the same numbers as at the origin.
    A power of two scales without rounding. Counters (lookups, steps) are unchanged too.

    Several media: the frame of the placed box nearest the eye (of those at the same
    distance, such as all that hold the eye, the smallest), as pbrt-v4 renders near its
    camera. The box around all of them would put its centre between media far apart, and
    then neither the camera nor the medium it sees could be placed: a cloud at the origin
    beside a haze box 1e8 away sat 5e7 from that centre, where float32 resolves 4 units, and
    the kernels rendered the bare sky. A medium far from the one chosen is placed only as
    precisely as float32 resolves its distance, as in any float32 renderer."""
    boxes = [placement(m)[:2] for m in scene.spec.media]
    eye = scene.camera.eye

    def nearness(box):
        lo, hi = box
        gap = math.sqrt(sum(max(lo[a] - eye[a], 0.0, eye[a] - hi[a]) ** 2 for a in range(3)))
        return gap, max(hi[a] - lo[a] for a in range(3))
    return box_frame(*min(boxes, key=nearness))


def camera_near(scene, forward):
    """World distance along ``forward`` from the camera to the plane its rays start on
    (params.near; reference/camera.py): just short of the nearest thing a camera ray can
    meet, each medium's world box and each sphere light by its bounding sphere, and not
    beyond a thin lens's plane in focus; 0 for a panoramic camera or one among them. The
    kernels then form a ray's origin near what it sees: a camera 1e8 box sizes away, whose
    float32 distances rounded to 8 units, saw a box of 2 as empty sky."""
    cam = scene.camera
    if cam.type == "panoramic":
        return 0.0
    spheres = []
    for m in scene.spec.media:
        lo, hi, _ = placement(m)
        spheres.append(([0.5 * (lo[a] + hi[a]) for a in range(3)],
                        0.5 * math.dist(lo, hi)))
    spheres += [(lt.position, lt.radius) for lt in scene.lights if lt.type == "sphere"]
    # A sixteenth of each radius short: the plane stays before everything, whatever the
    # rounding, and as near it as the objects' own sizes allow. What lies wholly behind the
    # camera's own plane no camera ray reaches (a sphere light there had set near to 0).
    gaps = []
    for c, r in spheres:
        ahead = sum((c[a] - cam.eye[a]) * forward[a] for a in range(3))
        reach = r * (1.0 + 2.0 ** -4)
        if ahead + reach > 0.0:
            gaps.append(ahead - reach)
    gap = min(gaps, default=0.0)
    # A thin lens's rays cross beyond the plane in focus: the plane stays before it, where a
    # ray's origin is within the lens's radius of the pinhole ray's (its rays from a focus
    # at 1e-30 left the lens almost sideways, and their points on a farther plane were 1e29
    # away).
    return max(0.0, min(gap, cam.focus_distance) if cam.aperture > 0.0 else gap)


def medium_space(lo, hi, m, centre, unit):
    """(bmin, bmax, xform) of the local box [lo, hi] placed by the 4x4 transform m (the one
    ``placement`` gives the kernels), packed: the box centred and scaled by a power of two
    as the scene frame is (so float32 sees a box of half-size near 1 wherever the user put
    it), and the 3x4 map from the scene frame (centre, unit) to that space, composed in
    float64."""
    c_l, u_l = box_frame(lo, hi)
    inv = np.linalg.inv(m)
    # scene frame f -> world centre + unit f -> local inv(M) world -> packed (local - c_l) / u_l
    lin = inv[:3, :3] * (unit / u_l)
    off = (inv[:3, :3] @ np.asarray(centre, float) + inv[:3, 3] - np.asarray(c_l)) / u_l
    xform = np.concatenate([lin, off[:, None]], axis=1).ravel()
    bmin = [(lo[i] - c_l[i]) / u_l for i in range(3)]
    bmax = [(hi[i] - c_l[i]) / u_l for i in range(3)]
    return bmin, bmax, xform


def near_box(lo, hi):
    """The box [lo, hi] of the scene frame grown by 2^-10 of its largest extent plus 2^-20 of
    its largest coordinate on every side: far more than the rounding of float32 slab tests
    (a few ulps), so a ray the kernels find missing it misses the box inside
    (``media_near``, kernels/medium.h)."""
    pad = 2.0 ** -10 * max(hi[a] - lo[a] for a in range(3)) + 2.0 ** -20 * max(
        abs(x) for x in (*lo, *hi))
    return [x - pad for x in lo], [x + pad for x in hi]


#: A scene packed for a backend: the parameter record [1], the light array, the medium record
#: [1], the density grid [nz, ny, nx], the majorant grid's per-cell maxima and minima, the
#: emission field grid, the blackbody table, a brick grid's index table and pool, and an
#: octree's first-child indices (placeholders when unused; with an octree, maj and mnr are its
#: per-node bounds).
Packed = namedtuple("Packed", ["params", "lights", "medium", "grid", "maj", "mnr", "emis",
                               "table", "bricks", "pool", "nodes", "parts", "env"])
#: One medium's record [1] and arrays, as Packed holds them; Packed.parts has one per medium
#: (Packed.medium is all the records [n], and its arrays are the first medium's).
MediumArrays = namedtuple("MediumArrays", ["medium", "grid", "maj", "mnr", "emis", "table",
                                           "bricks", "pool", "nodes"])


#: Sphere light radii the kernels take, in units of the scene frame: their squares, 2^-120
#: to 2^120, stay normal float32 numbers with room for the products around them.
SPHERE_RADIUS_RANGE = (2.0 ** -60, 2.0 ** 60)


def pack_scene(scene, real=np.float64, spp_seed=None):
    """A ``Packed`` scene with reals of type ``real`` (float64: the reference; float32: the
    kernels). Environment lights are summed into params.env; the light array holds the
    directional and point lights; the grid is a C-contiguous [z, y, x] array (a 1x1x1
    placeholder when homogeneous). Positions and extinction are in the scene frame
    (``scene_frame``). A value that overflows there is a SceneError (check_packed)."""
    with np.errstate(over="ignore", invalid="ignore"):   # check_packed names what overflowed
        pk = _pack_scene(scene, real, spp_seed)
    check_packed(scene, pk)
    return pk


def check_packed(scene, pk):
    """Raise SceneError(scene file, key) if a real of the packed records is not finite. The
    schema bounds every value alone; only their combination in the scene frame can
    overflow: a box of extent 6e38 (extinction is scale x unit), or a camera or light far
    from a box of extent 1e-38 (positions are (x - centre) / unit)."""
    centre, unit = scene_frame(scene)
    for records, key in ((pk.params, "camera"), (pk.medium, "medium.bounds"),
                         (pk.lights, "lights")):
        records = np.atleast_1d(records)
        for name in records.dtype.names or ():
            v = records[name]
            if v.dtype.kind == "f" and not np.isfinite(v).all():
                name = "eye" if name == "near" else name   # the eye's distance, packed apart
                raise SceneError(scene.file, key, f"{name} overflows float{8 * v.itemsize} in "
                                 f"the frame volmc renders in (positions relative to the "
                                 f"media's box, centre {_show3(centre)}, in units of {unit:g}; "
                                 "extinction per that unit): bring the box's size and the "
                                 "distances of the camera and lights from it closer")


def _show3(v):
    return "(" + ", ".join(f"{x:g}" for x in v) + ")"


def _pack_scene(scene, real, spp_seed):
    cam, rnd = scene.camera, scene.render
    centre, unit = scene_frame(scene)

    def local(x):
        return [(x[i] - centre[i]) / unit for i in range(3)]

    p = np.zeros(1, params_dtype(real))[0]
    w, h = cam.resolution
    p["width"], p["height"] = w, h
    f, r, u = camera_basis(cam)
    p["forward"], p["right"], p["up"] = f, r, u
    near = camera_near(scene, f)
    p["near"] = near / unit
    p["eye"] = local([cam.eye[i] + near * f[i] for i in range(3)])
    if cam.type == "orthographic":
        p["cam_type"] = CAMERA_ORTHOGRAPHIC
        p["half_height"] = 0.5 * cam.size / unit
    elif cam.type == "panoramic":
        p["cam_type"] = CAMERA_PANORAMIC
    else:
        p["cam_type"] = CAMERA_PERSPECTIVE
        p["half_height"] = math.tan(math.radians(cam.fov) * 0.5)
    p["aspect"] = w / h
    if cam.aperture > 0.0:
        # Kept inside float32's normal range, so that both backends see a lens (and draw
        # its sample) exactly when the scene has one. The slope is a ratio of lengths, the
        # same in every frame; a focus plane absurdly near the lens saturates it.
        p["aperture"] = min(max(cam.aperture / unit, FLOAT32_MIN_NORMAL), FLOAT32_MAX)
        p["lens_slope"] = min(cam.aperture / cam.focus_distance, LENS_SLOPE_MAX)
    env = [0.0, 0.0, 0.0]
    lights = []
    envmap = no_env(real)
    p["env_rot"] = np.eye(3).ravel()
    p["env_res"] = (1, 1)
    p["env_sampling"] = (ENV_SAMPLING_UNIFORM if rnd.env_sampling == "uniform"
                         else ENV_SAMPLING_IMPORTANCE)
    for i, lt in enumerate(scene.lights):
        if isinstance(lt, EnvironmentLight):
            p["has_env"] = 1
            env = [env[k] + lt.radiance[k] for k in range(3)]
            if lt.file is not None:   # the scene's one environment (schema.py)
                texels = light_texels(lt, scene.file, i)
                envmap = environment_distribution(texels, rnd.env_compensation, real)
                p["env_map"] = 1
                p["env_res"] = (texels.shape[1], texels.shape[0])
                env = [x * lt.strength for x in lt.radiance]
                if lt.rotation is not None:   # scene to map: the rotation's transpose
                    p["env_rot"] = np.asarray(lt.rotation, np.float64).T.ravel()
        elif isinstance(lt, DirectionalLight):
            # 1 - cos(angle / 2) as 2 sin^2(angle / 4): no cancellation for a small sun
            omc = 2.0 * math.sin(math.radians(lt.angle) / 4.0) ** 2
            lights.append((LIGHT_DIRECTIONAL, lt.direction, lt.irradiance, (0, 0, 0), omc, 0))
        elif isinstance(lt, PointLight):
            lights.append((LIGHT_POINT, local(lt.position),
                           [c / (unit * unit) for c in lt.intensity], (0, 0, 0), 0, 0))
        elif isinstance(lt, SpotLight):
            cos_outer = math.cos(math.radians(lt.angle))
            lights.append((LIGHT_SPOT, local(lt.position),
                           [c / (unit * unit) for c in lt.intensity], lt.direction, cos_outer,
                           cos_outer + lt.blend * (1.0 - cos_outer)))
        elif isinstance(lt, SphereLight):
            r = lt.radius / unit
            if not SPHERE_RADIUS_RANGE[0] <= r <= SPHERE_RADIUS_RANGE[1]:
                # the kernels' intersections and cone pdfs square it in float32: a radius of
                # 1e20 rendered black, one of 1e-20 NaN (an outside test)
                raise SceneError(scene.file, f"lights[{i}].radius",
                                 f"{lt.radius:g} is {r:g} units of the frame volmc renders in "
                                 f"(units of {unit:g}, the media's box); its square must stay "
                                 f"a normal float32: keep it within 2^-60 to 2^60 units")
            lights.append((LIGHT_SPHERE, local(lt.position), lt.radiance, (0, 0, 0), r, 0))
    p["env"] = env
    larr = np.zeros(len(lights), light_dtype(real))
    for i, (t, v, c, axis, size, inner) in enumerate(lights):
        larr[i]["type"], larr[i]["vec"], larr[i]["color"] = t, v, c
        larr[i]["axis"], larr[i]["size"], larr[i]["inner"] = axis, size, inner
    p["area_lights"] = sum(1 for x in lights if x[0] == LIGHT_SPHERE or
                           (x[0] == LIGHT_DIRECTIONAL and x[4] > 0.0))
    p["spheres"] = int(any(x[0] == LIGHT_SPHERE for x in lights))
    p["n_lights"] = len(lights)
    p["max_depth"] = rnd.max_depth
    p["rr_depth"] = rnd.rr_depth
    p["max_steps"] = rnd.max_steps
    p["mis"] = MIS_POWER if rnd.mis == "power" else MIS_BALANCE
    p["sampler"] = {"independent": SAMPLER_INDEPENDENT, "stratified": SAMPLER_STRATIFIED,
                    "sobol": SAMPLER_SOBOL}[rnd.sampler]
    p["spp"] = rnd.spp
    p["light_samples"] = rnd.light_samples
    p["equiangular"] = int(rnd.equiangular)
    p["rr"] = RR_ALBEDO if rnd.rr == "albedo" else RR_THROUGHPUT
    p["transparent"] = int(rnd.transparent_background)
    est = ESTIMATORS[rnd.transmittance]
    p["shadow_estimator"] = est.shadow_estimator_id
    p["view_estimator"] = est.view_estimator_id
    gridded = any(part.grid is not None for part in scene.media_scenes)
    p["decomposition"] = int(gridded and rnd.majorant in ("grid", "octree")
                             and rnd.free_flight == "decomposition")
    p["signed_samples"] = int(est.signed_in_renders and gridded)
    seed = rnd.seed if spp_seed is None else spp_seed
    p["seed_lo"] = seed & 0xFFFFFFFF
    p["seed_hi"] = seed >> 32
    params = np.zeros(1, params_dtype(real))
    params[0] = p
    from .scene.bricks import density_storage
    parts, tables64 = [], []
    storage = []
    for part in scene.media_scenes:
        stored = density_storage(part)
        storage.append(stored)
        if rnd.majorant == "octree":
            maj, mnr, nodes, depth = pack_octree(part, real, stored)
        else:
            (maj, mnr), nodes, depth = (pack_majorant(part, real, stored),
                                        np.zeros(1, np.int32), 0)
        medium, grid, bricks, pool = pack_medium(part, real, local, unit, maj.shape, stored,
                                                 centre, scene.spec)
        medium[0]["octree_depth"] = depth
        # The emitters' weights come from the float64 table in both packs: a float32 table
        # of a dim blackbody (100 K: 1e-80) is 0, which turned emission sampling off in the
        # kernels alone, and the twins drew different random numbers.
        emis, table64 = pack_emission(part, medium, real)
        tables64.append(table64)
        parts.append(MediumArrays(medium, grid, maj, mnr, emis,
                                  np.ascontiguousarray(table64, real), bricks, pool, nodes))
    if rnd.emission_sampling != "collision" and any(a.medium[0]["emission_kind"]
                                                    != EMISSION_NONE for a in parts):
        from .emitters import attach_emitters
        tables, total = attach_emitters([a.medium[0] for a in parts], storage,
                                        [a.emis for a in parts], tables64, real)
        parts = [a._replace(table=t) for a, t in zip(parts, tables)]
        if total > 0.0:
            params[0]["emission_sampling"] = (EMISSION_SAMPLING_LIGHT
                                              if rnd.emission_sampling == "light"
                                              else EMISSION_SAMPLING_MIS)
    # One medium: its record array itself, so that editing pk.medium edits what renders.
    media = parts[0].medium if len(parts) == 1 else np.concatenate([a.medium for a in parts])
    first = parts[0]
    return Packed(params, larr, media, first.grid, first.maj, first.mnr, first.emis,
                  first.table, first.bricks, first.pool, first.nodes, tuple(parts), envmap)


def env_buffer(pk):
    """The environment map as the kernels take it (kernels/environment.h): texels, pdf,
    marginal and conditional, flattened one after the other."""
    e = pk.env
    return np.ascontiguousarray(np.concatenate([np.ravel(e.texels), np.ravel(e.pdf),
                                                np.ravel(e.marginal),
                                                np.ravel(e.conditional)]))


def shared_buffers(pk):
    """(records [n], grid, maj, mnr, emis, table, bricks, pool, nodes) as the kernels take
    several media: each kind of array of every medium flattened one after the other, and
    each record's offsets (``*_off``) set to where its own begin. One medium's arrays are
    passed as they are, with offsets 0."""
    if len(pk.parts) == 1:
        return (pk.medium, pk.grid, pk.maj, pk.mnr, pk.emis, pk.table, pk.bricks, pk.pool,
                pk.nodes)
    media = pk.medium.copy()
    out = []
    for name, off in (("grid", "grid_off"), ("maj", "maj_off"), ("mnr", None),
                      ("emis", "emis_off"), ("table", "table_off"), ("bricks", "bricks_off"),
                      ("pool", "pool_off"), ("nodes", "nodes_off")):
        arrays = [np.ravel(getattr(a, name)) for a in pk.parts]
        starts = np.cumsum([0] + [x.size for x in arrays[:-1]])
        if starts[-1] + arrays[-1].size > 2**32 - 1:
            raise ValueError(f"the media's {name} arrays exceed 2^32 elements together")
        if off is not None:
            media[off] = starts
        out.append(np.concatenate(arrays))
    return (media, *out)


def pack_emission(scene, medium, real):
    """(emission field grid in ``real``, blackbody table in float64: the emitters' weights
    read it so in both packs) of the scene, and the emission fields of the medium record
    (set in place). Radiance and temperature are the same in the scene frame
    (pack.scene_frame): only sigma_a scales, and it is in the record's extinction."""
    from .emission import blackbody_table
    e = scene.medium.emission
    m = medium[0]
    m["emission_kind"] = EMISSION_NONE
    m["emission_dims"] = (1, 1, 1)
    if e is None:
        return np.zeros((1, 1, 1), real), np.zeros((2, 3))
    emis = np.ascontiguousarray(scene.emission_grid, dtype=real)
    nz, ny, nx = emis.shape
    m["emission_dims"] = (nx, ny, nz)
    if e.radiance is not None:
        m["emission_kind"] = EMISSION_RADIANCE
        m["emission_rgb"] = e.radiance
        return emis, np.zeros((2, 3))
    m["emission_kind"] = EMISSION_TEMPERATURE
    m["emission_rgb"] = (e.scale, e.scale, e.scale)
    table, per_kelvin = blackbody_table(float(scene.emission_grid.max()))
    m["table_scale"] = per_kelvin
    return emis, np.asarray(table, np.float64)


def pack_medium(scene, real, local, unit, maj_res, stored=None, centre=None, whole=None):
    """(medium record [1], density grid, brick table, brick pool) of the scene's medium in
    the scene frame (placeholders for what the storage does not use); ``maj_res`` is the
    shape (cz, cy, cx) of the majorant grid ``pack_majorant`` built, ``stored`` the grid as
    ``density_storage`` keeps it. One medium of several: ``scene`` is its part, ``centre``
    the frame's centre and ``whole`` the scene's SceneSpec (which decides the spectral mode
    and the chroma the media share)."""
    from .scene.bricks import BrickGrid, density_storage
    stored = density_storage(scene) if stored is None else stored
    bricks, pool = np.zeros((1, 1, 1), np.int32), np.zeros((1, 8, 8, 8), real)
    med, rnd = scene.medium, scene.render
    m = np.zeros(1, medium_dtype(real))[0]
    wlo, whi, placed = placement(med)
    whole = scene.spec if whole is None else whole
    if placed is None:
        lo, hi = local(wlo), local(whi)
    else:
        centre = scene_frame(scene)[0] if centre is None else centre
        lo, hi, m["xform"] = medium_space(*med.bounds, placed, centre, unit)
        m["transformed"] = 1
    m["bmin"], m["bmax"] = lo, hi
    m["near_min"], m["near_max"] = near_box(local(wlo), local(whi))
    m["inv_extent"] = [1.0 / (hi[i] - lo[i]) for i in range(3)]
    # Extinction is scale * density per channel: the record holds the largest channel's
    # scale (every majorant bounds it) and each channel's share of it.
    top = max(med.scale)
    sigma_scale = top * unit
    m["scale"] = sigma_scale
    # Several media share one chroma (schema.py): a black one takes the others'.
    shared = next((x for x in whole.media if max(x.scale) > 0.0), med)
    m["chroma"] = chroma(med.scale if top > 0.0 else shared.scale)
    m["spectral"] = SPECTRAL_GREY
    if whole.chromatic:
        m["spectral"] = {"channel": SPECTRAL_CHANNEL, "hero": SPECTRAL_HERO,
                         "tracking": SPECTRAL_TRACKING}[rnd.spectral]
    m["maj_res"] = (1, 1, 1)
    m["majorant_kind"] = MAJORANT_GLOBAL
    if scene.grid is None:
        m["density_kind"] = DENSITY_CONSTANT
        m["density"] = med.density.value
        m["dims"] = (1, 1, 1)
        # In the backend's precision, so the bound is the product the kernels form.
        sigma = real(m["scale"]) * real(m["density"])
        m["sigma_maj"] = m["sigma_min"] = sigma
        grid = np.zeros((1, 1, 1), real)
    else:
        if isinstance(stored, BrickGrid):
            m["density_kind"] = DENSITY_BRICKS
            grid = np.zeros((1, 1, 1), real)
            bricks, pool = stored.table, np.ascontiguousarray(stored.pool, dtype=real)
        else:
            m["density_kind"] = DENSITY_GRID
            grid = np.ascontiguousarray(stored, dtype=real)
        nz, ny, nx = stored.shape
        m["dims"] = (nx, ny, nz)
        # Trilinear interpolation never exceeds the largest voxel: a true global bound.
        m["sigma_maj"] = sigma_scale * float(stored.max())
        m["sigma_min"] = sigma_scale * float(stored.min())
        if rnd.majorant == "grid":
            m["majorant_kind"] = MAJORANT_GRID
            m["maj_res"] = maj_res
        elif rnd.majorant == "octree":
            m["majorant_kind"] = MAJORANT_OCTREE
    m["albedo"] = med.albedo
    m["phase_kind"] = PHASE_HG if med.phase.type == "hg" else PHASE_ISOTROPIC
    m["g"] = med.phase.g
    medium = np.zeros(1, medium_dtype(real))
    medium[0] = m
    return medium, grid, bricks, pool
