"""Denoised previews (``volmc render --denoise``, ``RenderedImage.denoised()``): Intel Open
Image Denoise's "RT" filter, through the ``pyoidn`` package (the ``volmc[denoise]`` extra).

A denoised image is a preview beside the unbiased one, never in its place: it is written to
its own file, whose metadata says it was denoised and from what. The filter reads the
linear HDR radiance and, when the render accumulated it, the albedo AOV (film.py: the
single-scattering albedo where each camera ray first scatters, so its pixel mean is the
coverage-weighted albedo, in [0, 1]). The AOV is itself a Monte Carlo mean and carries
noise, so the filter prefilters it (OIDN's ``cleanAux`` off). With a transparent background
the RGB is premultiplied and is denoised as it is; the alpha channel stays the unbiased
coverage.

No normal-like AOV: a noise-free density-gradient "normal" made the preview worse on the
cloud and the fire (volmc/bench/denoise_normal.py; docs/denoising.md).
"""

import numpy as np

from .scene.errors import SceneError

#: What the metadata of a denoised file records in its "denoised" attribute.
FILTER = "Intel Open Image Denoise, RT filter, HDR"


def oidn(file="command line", key="--denoise"):
    """The pyoidn module, or SceneError(file, key, how to install it)."""
    try:
        import pyoidn
    except ImportError:
        raise SceneError(file, key, "denoising needs Intel Open Image Denoise: "
                                    "pip install 'volmc[denoise]' (the pyoidn package)") from None
    return pyoidn


def oidn_version():
    """The version of the Open Image Denoise library pyoidn carries ("" if it does not
    say)."""
    oidn()
    try:
        from pyoidn import version
        return str(getattr(version, "oidn_version", "") or "")
    except ImportError:
        return ""


#: A pixel whose standard error is at most this fraction of its value has no noise a filter
#: could remove (float32's own rounding is 6e-8): the preview keeps its unbiased value.
NOISE_FREE_REL = 1e-6


def noise_free(image, variance, coverage=None):
    """Pixels [h, w] the preview keeps as rendered: the sky seen past the medium, an empty
    transparent background. A pixel's own samples cannot tell: at 2 spp, 70 of a cloud's
    pixels had only zeros, and a thin haze lets a pixel's few samples all pass. So kept are
    the pixels whose every channel is positive with a standard error (``variance`` of the
    mean, [h, w, 3]) of at most NOISE_FREE_REL of its value, and whose 8 neighbours are so
    too (a lone exact pixel inside a medium is luck), and given the ``coverage`` [h, w] (the
    film's alpha), the zeros no sample of which met a medium (where the alpha is 0, the
    premultiplied colour is 0). None where the variance is unknown (inf: 1 spp)."""
    m = np.asarray(image, np.float64)
    v = np.asarray(variance, np.float64)
    known = np.all(np.isfinite(v), axis=-1)
    sky = known & np.all((m > 0) & (v <= (NOISE_FREE_REL * m) ** 2), axis=-1)
    h, w = sky.shape
    pad = np.pad(sky, 1, constant_values=True)
    for dy in range(3):
        for dx in range(3):
            sky &= pad[dy:dy + h, dx:dx + w]
    if coverage is not None:
        sky |= known & (np.asarray(coverage) == 0) & np.all(m == 0, axis=-1)
    return sky


def denoise(image, albedo=None, file="command line", key="--denoise", normal=None,
            variance=None, coverage=None):
    """The denoised image, float32 [h, w, 3], of a linear HDR ``image`` [h, w, 3] guided by
    the mean ``albedo`` AOV [h, w, 3] (None: colour alone). Negative and non-finite values
    (signed samples, or an empty film) are clamped to 0 first: OIDN reads non-negative
    radiance. Given the ``variance`` of the mean [h, w, 3] (and the ``coverage``, the
    film's alpha [h, w]), noise-free pixels (noise_free) keep their value: the network
    moved a constant sky by up to a third next to a noisy medium, and gave an empty
    transparent background colour. ``normal`` [h, w, 3], a normal guide with the albedo,
    is for the measurement that found none worth having (volmc/bench/denoise_normal.py)."""
    pyoidn = oidn(file, key)
    color = np.asarray(image, np.float64)
    color = np.ascontiguousarray(np.where(np.isfinite(color), np.maximum(color, 0.0), 0.0),
                                 np.float32)
    guide = None
    if albedo is not None:
        a = np.asarray(albedo, np.float64)
        guide = np.ascontiguousarray(np.clip(np.where(np.isfinite(a), a, 0.0), 0.0, 1.0),
                                     np.float32)
    if normal is not None:
        normal = np.ascontiguousarray(normal, np.float32)
    out = np.asarray(pyoidn.denoise(color, guide, normal, hdr=True, quality="high"),
                     np.float32)
    if variance is not None:
        keep = noise_free(color, variance, coverage)
        out[keep] = color[keep]
    return out


def denoised_metadata(meta, with_albedo, source=None):
    """``meta`` (an image's EXR metadata) with the marks of a denoised preview: what
    filtered it, whether the albedo AOV guided it, and the unbiased file it came from."""
    out = dict(meta)
    version = oidn_version()
    out["denoised"] = FILTER + (f" (OIDN {version})" if version else "")
    out["denoised.albedo_aov"] = int(bool(with_albedo))
    if source is not None:
        out["denoised.from"] = str(source)
    return out


def denoised_path(path):
    """``<name>.denoised<ext>`` beside ``path`` (``cloud.exr`` -> ``cloud.denoised.exr``)."""
    import os
    stem, ext = os.path.splitext(os.fspath(path))
    return f"{stem}.denoised{ext}"


def denoise_film(film, file="command line", key="--denoise"):
    """The denoised RGBA image [h, w, 4] of a Film: its mean radiance denoised (guided by
    its albedo AOV when it has one) and its unbiased coverage as A."""
    rgb = denoise(film.mean(), film.albedo(), file, key, variance=film.variance_of_mean(),
                  coverage=film.alpha())
    return np.concatenate([rgb, film.alpha()[..., None].astype(np.float32)], axis=-1)


def write_denoised(film, meta, exr, png=None, exposure=0.0, operator="filmic",
                   transparent=False, file="command line", key="--denoise"):
    """Writes the denoised preview of ``film`` beside the unbiased EXR ``exr``, as
    ``denoised_path(exr)`` (float32 RGBA, ``meta`` marked by denoised_metadata) and, given
    the unbiased PNG's path ``png``, ``denoised_path(png)`` (tonemapped as that PNG, RGBA
    with a transparent background). Returns the paths written."""
    from .film import write_exr, write_png
    rgba = denoise_film(film, file, key)
    out = [denoised_path(exr)]
    write_exr(out[0], rgba, denoised_metadata(meta, film.has_albedo, exr))
    if png is not None:
        out.append(denoised_path(png))
        write_png(out[1], rgba[..., :3], exposure, operator,
                  alpha=rgba[..., 3] if transparent else None)
    return out
