"""Film: per-pixel accumulation, variance of the mean, EXR and PNG output, image metrics.

Every render accumulates, per pixel and channel, the sum of its sample values and the sum
of their squares, so it knows its own noise: the variance of the pixel mean is
``(sum_sq / n - mean^2) / (n - 1)`` (unbiased sample variance divided by n).

The channels are R, G, B and A. A sample's A is 1 - T, T the estimate of the camera ray's
transmittance to the background that its own path makes (the medium's coverage; see
docs/scene_format.md, ``render.transparent_background``). A film made with ``albedo``
(``volmc render --denoise``) has three more: the albedo AOV a denoiser reads (denoise.py).
A sample's albedo is the single-scattering albedo sigma_s / sigma_t (RGB) of the medium its
camera ray first scatters in, and 0 when the camera ray does not scatter (it escapes, ends
on a sphere light, or the scene cannot scatter); so a pixel's mean is the coverage-weighted
albedo, sum_k albedo_k P(the first collision is in medium k), in [0, 1].

Images are float arrays [height, width, 3] of linear RGB, row 0 at the top; ``alpha()`` is
[height, width].
"""

import math
import os

import numpy as np

from .outputs import written_whole

#: Metadata attribute prefix in EXR headers.
META_PREFIX = "volmc:"


#: Channels a film accumulates per pixel: RGBA ...
CHANNELS = 4
#: ... and with the albedo AOV, its R, G and B after them.
ALBEDO_CHANNELS = 3


class Film:
    """Running per-pixel sums for a width x height RGBA image (and the albedo AOV with
    ``albedo``)."""

    def __init__(self, width, height, albedo=False):
        self.width = int(width)
        self.height = int(height)
        self.channels = CHANNELS + (ALBEDO_CHANNELS if albedo else 0)
        self.sum = np.zeros((self.height, self.width, self.channels), np.float64)
        self.sum_sq = np.zeros((self.height, self.width, self.channels), np.float64)
        self.spp = 0

    @property
    def has_albedo(self):
        return self.channels > CHANNELS

    def albedo(self):
        """Per-pixel mean albedo AOV [h, w, 3] (module docstring), or None without it."""
        if not self.has_albedo:
            return None
        return self.sum[..., CHANNELS:] / max(self.spp, 1)

    def mean(self):
        """Per-pixel mean radiance [h, w, 3] (zeros before the first sample)."""
        return self.sum[..., :3] / max(self.spp, 1)

    def alpha(self):
        """Per-pixel mean coverage A = 1 - T [h, w] (zeros before the first sample)."""
        return self.sum[..., 3] / max(self.spp, 1)

    def rgba(self):
        """[h, w, 4]: the mean radiance and the coverage."""
        return self.sum[..., :CHANNELS] / max(self.spp, 1)

    def variance_of_mean(self, alpha=False):
        """Per-pixel variance of the mean [h, w, 3] ([h, w] for the coverage with alpha);
        inf with fewer than 2 samples."""
        c = 3 if alpha else slice(0, 3)
        n = self.spp
        if n < 2:
            return np.full_like(self.sum[..., c], np.inf)
        m = self.sum[..., c] / n
        var = np.maximum(self.sum_sq[..., c] / n - m * m, 0.0) * (n / (n - 1))
        return var / n


def variance_path(exr):
    """``<name>.var.exr`` beside the EXR ``exr``: where --variance writes the per-pixel
    variance of the mean (``cloud.exr`` -> ``cloud.var.exr``)."""
    return os.path.splitext(os.fspath(exr))[0] + ".var.exr"


def write_exr(path, image, metadata=None):
    """Write a float32 RGB or RGBA EXR (channels R, G, B and A for an [h, w, 4] image; ZIP
    compression) with string/number metadata.

    Each channel is passed to OpenEXR as its own C-contiguous array: OpenEXR 3.5's bindings
    write wrong pixels for strided views such as ``image[..., 0]``.
    """
    import OpenEXR
    image = np.asarray(image, dtype=np.float32)
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"expected an [h, w, 3] or [h, w, 4] image, got shape {image.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for k, v in (metadata or {}).items():
        if isinstance(v, bool):
            v = int(v)
        elif not isinstance(v, (int, float, str)):
            v = str(v)
        header[META_PREFIX + k] = v
    channels = {c: np.ascontiguousarray(image[..., i])
                for i, c in enumerate("RGBA"[:image.shape[2]])}
    with written_whole(path, ".exr") as tmp, OpenEXR.File(header, channels) as f:
        f.write(tmp)


def rescue_exr(path, error, image, metadata=None, what="the image"):
    """After writing ``path`` failed with ``error`` (a full disk, a directory removed or gone
    read-only meanwhile), write ``image`` (as write_exr) to a new file in the system's
    temporary directory, the place of last resort, so that no render is lost. Returns the
    one-line error to raise, naming the copy."""
    import tempfile
    fd, rescue = tempfile.mkstemp(prefix="volmc-rescued-", suffix=".exr")
    os.close(fd)
    try:
        write_exr(rescue, image, metadata)
    except (OSError, RuntimeError):   # the temporary directory's disk is full too
        os.unlink(rescue)
        return f"could not write {path} ({error}), nor a copy in the temporary directory"
    return f"could not write {path} ({error}); {what} is saved as {rescue}"


def read_exr(path, alpha=False):
    """Read an RGB EXR. Returns (image float32 [h, w, 3], metadata dict without the prefix);
    with alpha, the image is [h, w, 4] with the A channel (1 where the file has none)."""
    import OpenEXR
    with OpenEXR.File(str(path), separate_channels=True) as f:
        ch = f.channels()
        img = np.stack([np.asarray(ch[c].pixels, np.float32) for c in "RGB"], axis=-1)
        if alpha:
            a = np.asarray(ch["A"].pixels, np.float32) if "A" in ch else \
                np.ones(img.shape[:2], np.float32)
            img = np.concatenate([img, a[..., None]], axis=-1)
        meta = {k[len(META_PREFIX):]: v for k, v in f.header().items()
                if k.startswith(META_PREFIX)}
    return img, meta


def srgb_encode(x):
    """Linear [0, 1] -> sRGB-encoded [0, 1] (IEC 61966-2-1 transfer function)."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


#: The tone operators of ``tonemap``, and the largest |exposure| in stops (2 ** exposure and
#: the scaled radiance stay finite floats).
TONE_OPERATORS = ("filmic", "clamp")
MAX_EXPOSURE = 100.0


def tonemap(image, exposure=0.0, operator="filmic"):
    """Linear radiance -> display [0, 1]: scale by 2^exposure, then a tone curve, then sRGB.

    ``operator``: "filmic" (Narkowicz's fit of the ACES curve, gentle highlight roll-off),
    or "clamp" (plain clipping, for scenes whose values are already in [0, 1]).
    """
    x = np.asarray(image, np.float64) * (2.0 ** exposure)
    x = np.where(np.isfinite(x), np.maximum(x, 0.0), 0.0)
    if operator == "filmic":
        a, b, c, d, e = 2.51, 0.03, 2.43, 0.59, 0.14
        x = (x * (a * x + b)) / (x * (c * x + d) + e)
    elif operator != "clamp":
        raise ValueError(f"unknown tone operator {operator!r}")
    return srgb_encode(x)


#: Rows tonemapped at a time by write_png, so its float64 temporaries stay bounded.
PNG_BAND_ROWS = 256


def write_png(path, image, exposure=0.0, operator="filmic", alpha=None):
    """Write a tonemapped 8-bit sRGB PNG preview of a linear image (tonemapped in bands of
    PNG_BAND_ROWS rows: the same pixels, with temporaries of one band). With ``alpha``
    ([h, w] coverage), the PNG is RGBA: PNG's alpha is straight, so the premultiplied
    colour is divided by the coverage before the tone curve (0 where nothing covers)."""
    from matplotlib import image as mpimg
    out = png_pixels(image, exposure, operator, alpha)
    with written_whole(path, os.path.splitext(str(path))[1]) as tmp:
        mpimg.imsave(tmp, out)


def png_pixels(image, exposure=0.0, operator="filmic", alpha=None):
    """The 8-bit sRGB pixels (uint8 [h, w, 3], or [h, w, 4] with ``alpha``) of write_png."""
    h, w = np.shape(image)[:2]
    out = np.empty((h, w, 3 if alpha is None else 4), np.uint8)
    for y in range(0, h, PNG_BAND_ROWS):
        band = np.asarray(image[y:y + PNG_BAND_ROWS], np.float64)
        if alpha is not None:
            a = np.clip(np.asarray(alpha[y:y + PNG_BAND_ROWS], np.float64), 0.0, 1.0)
            band = np.where(a[..., None] > 1e-6, band / np.maximum(a, 1e-6)[..., None], 0.0)
            out[y:y + PNG_BAND_ROWS, :, 3] = (a * 255.0 + 0.5).astype(np.uint8)
        out[y:y + PNG_BAND_ROWS, :, :3] = (tonemap(band, exposure, operator) * 255.0 + 0.5) \
            .astype(np.uint8)
    return out


def rmse(image, reference):
    """Root-mean-square error between two images (all pixels and channels)."""
    d = np.asarray(image, np.float64) - np.asarray(reference, np.float64)
    return math.sqrt(float(np.mean(d * d)))
