"""Pack a Scene into the parameter record, light array and grid every backend consumes."""

import math

import numpy as np

from .constants import (CAMERA_ORTHOGRAPHIC, CAMERA_PERSPECTIVE, LIGHT_DIRECTIONAL, LIGHT_POINT,
                        PHASE_HG, PHASE_ISOTROPIC)
from .params import light_dtype, params_dtype
from .reference import estimators as E
from .scene.schema import DirectionalLight, EnvironmentLight, PointLight

def pack_majorant(scene, real=np.float64):
    """(maxima, minima) density bounds per majorant cell [cz, cy, cx] for render.majorant =
    "grid" with a density grid, else 1x1x1 arrays holding the global bounds."""
    from .reference.majorant import build_majorant_grid
    if scene.grid is None:
        return np.zeros((1, 1, 1), real), np.zeros((1, 1, 1), real)
    if scene.render.majorant != "grid":
        return (np.full((1, 1, 1), scene.grid.max(), real),
                np.full((1, 1, 1), scene.grid.min(), real))
    res = scene.render.majorant_resolution
    mx, mn = build_majorant_grid(scene.grid, tuple(reversed(res)) if res else None)
    return np.ascontiguousarray(mx, real), np.ascontiguousarray(mn, real)


def medium_array(params):
    """The extinction-source array (reference/extinction.py layout) of a packed grid scene."""
    from .reference.extinction import make_grid_medium
    p = params[0]
    return make_grid_medium(tuple(p["bmin"]), tuple(p["bmax"]), float(p["scale"]))


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
    """Guard "scene frame" (HARD_CASES 11, 12): the frame every backend renders in.

    Returns (centre, unit): the centre of the medium box and a power of two close to its
    largest half-extent. Positions are packed as (x - centre) / unit (in float64, before any
    float32 rounding), extinction as scale * unit, point-light intensities as I / unit^2;
    directions, radiances and irradiances are unchanged. Radiance along every ray is the same
    in both frames, so the image is too, but the kernels' float32 then always sees a box of
    half-size in [0.7, 1.4] at the origin: a scene translated 1e7 units away (where float32
    has an ulp of 1) or scaled by 1e-4 or 1e4 renders from the same numbers as at the origin.
    A power of two scales without rounding. Counters (lookups, steps) are unchanged too."""
    lo, hi = scene.medium.bounds
    centre = tuple(0.5 * (lo[i] + hi[i]) for i in range(3))
    half = max(0.5 * (hi[i] - lo[i]) for i in range(3))
    return centre, 2.0 ** round(math.log2(half))


def pack_scene(scene, real=np.float64, spp_seed=None):
    """Return (params[1], lights[n], grid) for a Scene.

    ``params`` is a one-element array of ``params_dtype(real)``; ``lights`` holds the
    directional and point lights (environment lights are summed into params.env);
    ``grid`` is a C-contiguous [z, y, x] array of ``real`` (a 1x1x1 dummy when homogeneous).
    Positions and extinction are in the scene frame (``scene_frame``).
    """
    cam, med, rnd = scene.camera, scene.medium, scene.render
    centre, unit = scene_frame(scene)

    def local(x):
        return [(x[i] - centre[i]) / unit for i in range(3)]

    sigma_scale = med.scale * unit
    p = np.zeros(1, params_dtype(real))[0]
    w, h = cam.resolution
    p["width"], p["height"] = w, h
    f, r, u = camera_basis(cam)
    p["forward"], p["right"], p["up"] = f, r, u
    p["eye"] = local(cam.eye)
    if cam.type == "orthographic":
        p["cam_type"] = CAMERA_ORTHOGRAPHIC
        p["half_height"] = 0.5 * cam.size / unit
    else:
        p["cam_type"] = CAMERA_PERSPECTIVE
        p["half_height"] = math.tan(math.radians(cam.fov) * 0.5)
    p["aspect"] = w / h
    lo, hi = local(med.bounds[0]), local(med.bounds[1])
    p["bmin"], p["bmax"] = lo, hi
    p["inv_extent"] = [1.0 / (hi[i] - lo[i]) for i in range(3)]
    p["scale"] = sigma_scale
    if scene.grid is None:
        p["has_grid"] = 0
        p["density"] = med.density.value
        p["majorant"] = sigma_scale * med.density.value
        grid = np.zeros((1, 1, 1), real)
    else:
        p["has_grid"] = 1
        grid = np.ascontiguousarray(scene.grid, dtype=real)
        # Trilinear interpolation never exceeds the largest voxel: a true global bound.
        p["majorant"] = sigma_scale * float(scene.grid.max())
        p["minorant"] = sigma_scale * float(scene.grid.min())
        p["density"] = 0.0
    p["albedo"] = med.albedo
    p["phase_kind"] = PHASE_HG if med.phase.type == "hg" else PHASE_ISOTROPIC
    p["g"] = med.phase.g
    env = [0.0, 0.0, 0.0]
    lights = []
    for lt in scene.lights:
        if isinstance(lt, EnvironmentLight):
            p["has_env"] = 1
            env = [env[i] + lt.radiance[i] for i in range(3)]
        elif isinstance(lt, DirectionalLight):
            lights.append((LIGHT_DIRECTIONAL, lt.direction, lt.irradiance))
        elif isinstance(lt, PointLight):
            lights.append((LIGHT_POINT, local(lt.position),
                           [c / (unit * unit) for c in lt.intensity]))
    p["env"] = env
    larr = np.zeros(len(lights), light_dtype(real))
    for i, (t, v, c) in enumerate(lights):
        larr[i]["type"], larr[i]["vec"], larr[i]["color"] = t, v, c
    p["n_lights"] = len(lights)
    p["max_depth"] = rnd.max_depth
    p["rr_depth"] = rnd.rr_depth
    p["max_steps"] = rnd.max_steps
    p["shadow_estimator"] = E.ESTIMATORS[rnd.transmittance][0]
    if scene.grid is not None and rnd.majorant == "grid":
        from .reference.majorant import auto_resolution
        p["has_majorant_grid"] = 1
        p["decomposition"] = int(rnd.free_flight == "decomposition")
        res = rnd.majorant_resolution
        p["maj_res"] = tuple(reversed(res)) if res else auto_resolution(scene.grid.shape)
    else:
        p["maj_res"] = (1, 1, 1)
    p["signed_samples"] = int(rnd.transmittance in E.SIGNED and scene.grid is not None)
    seed = rnd.seed if spp_seed is None else spp_seed
    p["seed_lo"] = seed & 0xFFFFFFFF
    p["seed_hi"] = seed >> 32
    params = np.zeros(1, params_dtype(real))
    params[0] = p
    return params, larr, grid
