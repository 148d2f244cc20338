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
    pk = pack_scene(scene, np.float64)
    prm, rec = pk.params[0], pk.medium[0]
    grid = np.asarray(scene.grid, np.float64)   # [nz, ny, nx]
    bmin, bmax = np.asarray(rec["bmin"]), np.asarray(rec["bmax"])
    scale = float(np.max(rec["scale"]))
    e, f, r, u = (np.asarray(prm[k], np.float64) for k in ("eye", "forward", "right", "up"))
    w, h = scene.camera.resolution
    ys, xs = np.mgrid[0:h, 0:w]
    sx = (2.0 * (xs + 0.5) / w - 1.0) * prm["half_height"] * prm["aspect"]
    sy = (1.0 - 2.0 * (ys + 0.5) / h) * prm["half_height"]
    d = f + sx[..., None] * r + sy[..., None] * u
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
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
    import pyoidn
    import volmc
    argv = sys.argv[1:] if argv is None else argv
    path = argv[0]
    width = int(argv[1]) if len(argv) > 1 else 128
    w0, h0 = volmc.load_scene(path).camera.resolution
    scene = volmc.load_scene(path, {"camera.resolution": [width, max(1, round(width * h0 / w0))]})
    normal, share = _view_normals(scene)
    ref = volmc.render(scene, spp=2048, seed=1_000_003, progress=False)
    ref_img, ref_var = np.asarray(ref.image, np.float64), float(np.mean(ref.variance))

    def rmse(a):
        err = np.mean((np.asarray(a, np.float64) - ref_img) ** 2) - ref_var
        return float(np.sqrt(max(err, 0.0)))
    print(f"{path}: {share:.2f} of the pixels reach optical depth 1")
    print("spp | noisy | albedo | albedo + normal | ratio")
    for spp in (4, 16, 64):
        img = volmc.render(scene, spp=spp, progress=False, albedo=True)
        col = np.ascontiguousarray(np.maximum(img.image, 0.0), np.float32)
        alb = np.ascontiguousarray(np.clip(img.albedo, 0.0, 1.0), np.float32)
        a = rmse(pyoidn.denoise(col, alb, hdr=True))
        b = rmse(pyoidn.denoise(col, alb, np.ascontiguousarray(normal), hdr=True))
        print(f"{spp} | {rmse(img.image):.4g} | {a:.4g} | {b:.4g} | {b / a:.3f}")


if __name__ == "__main__":
    main()
