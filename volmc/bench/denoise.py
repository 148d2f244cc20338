"""What the denoised preview gains: ``volmc bench denoise``.

Each scene (default: the gallery's) is rendered by OpenCL at a small resolution at each
level of an spp ladder with the albedo AOV, and once more at ``reference_spp`` with another
seed as the reference. Per level: the mean squared error of the unbiased image, of its
denoised preview guided by the albedo AOV, and of the preview from the colour alone.

The reference has noise of its own. Its film knows it: the mean of its per-pixel variance
of the mean is subtracted from every squared error (the rendered images are independent
of the reference, so E[(x - ref)^2] = MSE(x) + Var(ref)). A denoised error near the
reference's own variance is then poorly resolved, which the report says by printing the
reference's share.

"Worth" is the spp the unbiased renderer needs to reach the preview's error: spp x
MSE(noisy) / MSE(denoised), since the unbiased error falls as 1/spp. It is a measure of
the filter on these scenes, not a claim of equal images: the preview is biased (it blurs
what it takes for noise), and its error stops falling once the bias dominates.
"""

import time
from pathlib import Path

import numpy as np

from ..resources import scenes_dir

#: The gallery scenes the benchmark renders by default.
GALLERY = ("cloud.toml", "gallery/plume.toml", "gallery/fire.toml", "gallery/sunrise.toml",
           "gallery/spotlight.toml")


def scene_paths(paths):
    """The scenes to measure: ``paths``, else the gallery's."""
    return [Path(p) for p in paths] if paths else [scenes_dir() / g for g in GALLERY]


def mse(image, ref, ref_var):
    """Mean squared error of ``image`` against the reference image ``ref``, whose mean
    variance of the mean ``ref_var`` is subtracted (module docstring)."""
    d = np.asarray(image, np.float64) - ref
    return float(np.mean(d * d) - ref_var)


def scene_and_reference(path, width, reference_spp=2048, lanes=None):
    """(scene, resolution, reference image float64, its mean variance of the mean, seconds):
    the scene at ``path`` resized to ``width`` pixels across, and its reference render (a
    seed of its own, independent of the renders measured against it)."""
    from ..api import render
    from ..render import whole
    from ..scene.loading import load_scene, read_raw
    from ..scene.schema import validate
    w0, h0 = validate(read_raw(path), str(path)).camera.resolution   # (no grid loaded)
    res = [int(width), max(1, round(width * h0 / w0))]
    scene = load_scene(path, {"camera.resolution": res})
    t = time.perf_counter()
    ref = whole(render(scene, spp=reference_spp, seed=1_000_003, progress=False, lanes=lanes))
    return (scene, res, np.asarray(ref.image, np.float64), float(np.mean(ref.variance)),
            time.perf_counter() - t)


def measure(path, width=160, spp_levels=(4, 16, 64), reference_spp=2048, lanes=None,
            log=print):
    """The rows of one scene (module docstring)."""
    from ..api import render
    from ..render import whole
    from ..denoise import denoise
    scene, res, ref_img, ref_var, seconds = scene_and_reference(path, width, reference_spp,
                                                                lanes)
    log(f"{Path(path).name}: reference {reference_spp} spp in {seconds:.0f} s")
    rows = []
    for spp in spp_levels:
        img = whole(render(scene, spp=spp, progress=False, lanes=lanes, albedo=True))
        t = time.perf_counter()
        with_albedo = img.denoised()
        seconds = time.perf_counter() - t
        colour = denoise(img.image)
        row = {"spp": int(spp), "render_seconds": img.seconds, "denoise_seconds": seconds,
               "mse_noisy": mse(img.image, ref_img, ref_var),
               "mse_denoised": mse(with_albedo, ref_img, ref_var),
               "mse_denoised_colour_only": mse(colour, ref_img, ref_var)}
        row["worth_spp"] = spp * row["mse_noisy"] / max(row["mse_denoised"], 1e-30)
        rows.append(row)
        log(f"  {spp} spp done")
    return {"scene": str(path), "resolution": res, "reference_spp": reference_spp,
            "reference_variance": ref_var, "mean_square_of_reference": float(np.mean(
                ref_img * ref_img)), "rows": rows}


def run(paths=(), width=160, spp_levels=(4, 16, 64), reference_spp=2048, lanes=None,
        log=print):
    return {"scenes": [measure(p, width, spp_levels, reference_spp, lanes, log)
                       for p in scene_paths(paths)]}


def print_report(report, log=print):
    log("denoised preview against the unbiased image: RMSE against the reference (its own "
        "noise subtracted)")
    log("scene | spp | noisy | denoised (albedo) | denoised (colour) | worth spp | "
        "OIDN s")
    for s in report["scenes"]:
        name = Path(s["scene"]).name
        for r in s["rows"]:
            rm = [np.sqrt(max(r[k], 0.0)) for k in ("mse_noisy", "mse_denoised",
                                                      "mse_denoised_colour_only")]
            log(f"  {name} {s['resolution'][0]}x{s['resolution'][1]} | {r['spp']} | "
                f"{rm[0]:.4g} | {rm[1]:.4g} | {rm[2]:.4g} | {r['worth_spp']:.0f} | "
                f"{r['denoise_seconds']:.2f}")
        share = s["reference_variance"] / max(s["rows"][-1]["mse_denoised"], 1e-30)
        log(f"  ({name}: the reference's own variance is {share:.2g}x the last level's "
            "denoised MSE)")
