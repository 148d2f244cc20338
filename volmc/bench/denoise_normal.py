"""Would a normal-like AOV help the denoiser? ``python -m volmc.bench.denoise_normal SCENE``.

A volume has no surface normal; the nearest thing is the density gradient where the camera
ray's optical depth reaches 1. This computes that "normal" without noise, by ray marching
the scene's one density grid (400 steps per ray, trilinear, in view space; 0 where the
depth never reaches 1), which is the best a kernel-accumulated one could be. It then
denoises renders at 4, 16 and 64 spp with the albedo AOV alone and with the albedo AOV and
this normal, and prints their RMSE against a 2048-spp reference (its own variance
subtracted). Needs scipy and the ``volmc[denoise]`` extra. docs/denoising.md has the figures.
"""

import sys

import numpy as np


def _view_normals(scene, steps=400):
    """The noise-free normal image [H, W, 3] (module docstring) and the fraction of pixels
    whose camera ray reaches optical depth 1."""
    from scipy.ndimage import map_coordinates
    from ..pack import pack_scene
    from ..reference.camera import camera_ray
    pk = pack_scene(scene, np.float64)
    prm, rec = pk.params[0], pk.medium[0]
    grid = np.asarray(scene.grid, np.float64)   # [nz, ny, nx]
    bmin, bmax = np.asarray(rec["bmin"]), np.asarray(rec["bmax"])
    scale = float(np.max(rec["scale"]))
    f, r, u = (np.asarray(prm[k], np.float64) for k in ("forward", "right", "up"))
    w, h = scene.camera.resolution
    # Each pixel's centre ray, through the lens centre (the camera's own ray generation).
    rays = [camera_ray(prm, x, y, 0.5, 0.5, 0.5, 0.5) for y in range(h) for x in range(w)]
    e = np.array([o for o, _ in rays]).reshape(h, w, 3)
    d = np.array([v for _, v in rays]).reshape(h, w, 3)
    inv = 1.0 / np.where(d == 0.0, 1e-30, d)
    ta, tb = (bmin - e) * inv, (bmax - e) * inv
    t0 = np.maximum(np.minimum(ta, tb).max(axis=-1), 0.0)
    t1 = np.maximum(ta, tb).min(axis=-1)
    hit = t1 > t0
    n = np.array(grid.shape[::-1], np.float64)   # (nx, ny, nz)

    def lookup(a, p):
        c = (p - bmin) / (bmax - bmin) * n - 0.5
        return map_coordinates(a, [c[..., 2].ravel(), c[..., 1].ravel(), c[..., 0].ravel()],
                               order=1, mode="nearest").reshape(p.shape[:-1])
    tau = np.zeros((h, w))
    found = np.zeros((h, w), bool)
    at = np.zeros((h, w, 3))
    dt = np.where(hit, (t1 - t0) / steps, 0.0)
    for i in range(steps):
        p = e + d * (t0 + (i + 0.5) * dt)[..., None]
        tau += scale * lookup(grid, p) * dt
        new = hit & ~found & (tau >= 1.0)
        at[new] = p[new]
        found |= new
    g = np.stack([lookup(a, at) for a in np.gradient(grid)[::-1]], -1)   # x, y, z
    nrm = -g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-12)
    view = np.stack([(nrm * r).sum(-1), (nrm * u).sum(-1), -(nrm * f).sum(-1)], -1)
    view[~found] = 0.0
    return view.astype(np.float32), float(found.mean())


def main(argv=None):
    import argparse
    import volmc
    from ..denoise import denoise
    from ..scene.errors import SceneError
    from ..scene.loading import load_scene
    from .denoise import mse, scene_and_reference
    p = argparse.ArgumentParser(prog="python -m volmc.bench.denoise_normal",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("scene", help="a scene of one medium whose density is a grid")
    p.add_argument("width", nargs="?", type=int, default=128,
                   help="pixels across (default 128)")
    args = p.parse_args(argv)
    try:
        scene = load_scene(args.scene)
    except SceneError as e:
        p.exit(2, f"volmc: error: {e}\n")
    if len(scene.media) != 1 or scene.grid is None:   # (before the reference's minutes)
        p.exit(2, f"volmc: error: {args.scene}: medium.density: the normal is the gradient "
                  "of one medium's density grid, and this scene has none\n")
    if args.width < 1:
        p.error(f"width: at least 1, got {args.width}")
    scene, _, ref_img, ref_var, _ = scene_and_reference(args.scene, args.width)
    normal, share = _view_normals(scene)

    def rmse(a):
        return float(np.sqrt(max(mse(a, ref_img, ref_var), 0.0)))
    print(f"{args.scene}: {share:.2f} of the pixels reach optical depth 1")
    print("spp | noisy | albedo | albedo + normal | ratio")
    for spp in (4, 16, 64):
        img = volmc.render(scene, spp=spp, progress=False, albedo=True)
        a = rmse(denoise(img.image, img.albedo))
        b = rmse(denoise(img.image, img.albedo, normal=normal))
        print(f"{spp} | {rmse(img.image):.4g} | {a:.4g} | {b:.4g} | {b / a:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
