"""Tracking-loop walks on either backend for the tests: the reference's ``track_batch`` and
its twin, the ``t_track`` test kernel, on the same rays, media and random streams."""

import numpy as np

from volmc.params import medium_dtype
from volmc.reference.medium import make_grid_medium
from volmc.reference.tracking import track_batch

NO_MAJORANT_GRID = np.zeros((1, 1, 1))


def grid_media(bmin, bmax, scale, grid, n_rays, sigma_maj=None, sigma_min=0.0,
               maj_res=None):
    """n_rays copies of a grid medium's record: the global majorant sigma_maj (default
    scale * max), minorant sigma_min, or the majorant grid of resolution maj_res."""
    from volmc.constants import MAJORANT_GRID
    nz, ny, nx = np.shape(grid)
    m = make_grid_medium(tuple(bmin), tuple(bmax), scale, (nx, ny, nz))
    m["sigma_maj"] = scale * float(np.max(grid)) if sigma_maj is None else sigma_maj
    m["sigma_min"] = sigma_min
    if maj_res is not None:
        m["majorant_kind"] = MAJORANT_GRID
        m["maj_res"] = maj_res
    return np.repeat(np.atleast_1d(m), n_rays)


def walks(backend, technique, use_control, media, grid, rays, n_per_ray, seed,
          max_steps=1_000_000, maj=NO_MAJORANT_GRID, mnr=NO_MAJORANT_GRID):
    """(t, T, lookups) of n_per_ray walks per ray: t is the collision distance, -1 on escape,
    -2 if capped; T the transmittance estimate (first channel; ``walks_rgb`` for all)."""
    t, T, lk = walks_rgb(backend, technique, use_control, media, grid, rays, n_per_ray, seed,
                         max_steps, maj, mnr)
    return t, T[:, 0].copy(), lk


def walks_rgb(backend, technique, use_control, media, grid, rays, n_per_ray, seed,
              max_steps=1_000_000, maj=NO_MAJORANT_GRID, mnr=NO_MAJORANT_GRID):
    """``walks`` with the RGB estimate T [n, 3] (colour-dependent media)."""
    rays = np.asarray(rays, np.float64)
    if backend == "numba":
        return track_batch(technique, use_control, media.astype(medium_dtype(np.float64)),
                           np.asarray(grid, np.float64), np.asarray(maj, np.float64),
                           np.asarray(mnr, np.float64), rays, n_per_ray, np.uint64(seed),
                           max_steps)
    from cl_harness import out_buf, run_rays, to_dev
    n = len(rays) * n_per_ray
    t, tb = out_buf(n)
    T, Tb = out_buf(3 * n)
    lk, lb = out_buf(n, np.uint64)
    run_rays("t_track", len(rays), n_per_ray, np.int32(technique), np.int32(use_control),
        to_dev(media.astype(medium_dtype(np.float32))), to_dev(np.asarray(grid, np.float32)),
        to_dev(np.asarray(maj, np.float32)), to_dev(np.asarray(mnr, np.float32)),
        to_dev(rays.astype(np.float32).ravel()), np.int32(n_per_ray), np.uint64(seed),
        np.int32(max_steps), tb, Tb, lb, outs=[(t, tb), (T, Tb), (lk, lb)])
    return t.astype(np.float64), T.reshape(n, 3).astype(np.float64), lk.astype(np.int64)
