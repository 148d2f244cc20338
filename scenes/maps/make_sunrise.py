"""Writes sunrise.exr, the gallery's HDR sky, from Blender's bundled "sunrise" studio light
(Greg Zaal, Poly Haven "spruit_sunrise", CC0; LICENSE.txt beside this script):

    python scenes/maps/make_sunrise.py <bpy>/datafiles/studiolights/world/sunrise.exr

The bundled file (1024 x 512, DWAB-compressed float) holds 358 texels slightly below zero
(down to -0.0007), left by the lossy compression; volmc refuses negative radiance, so they
are set to 0. The map is then averaged 2 x 2 to 512 x 256 (the sun keeps its power) and
written as float32 with ZIP compression."""

import sys

import numpy as np
import OpenEXR


def main(src, dst="scenes/maps/sunrise.exr"):
    with OpenEXR.File(src, separate_channels=True) as f:
        img = np.stack([np.asarray(f.channels()[c].pixels, np.float64) for c in "RGB"], -1)
    img = np.maximum(img, 0.0)
    h, w = img.shape[:2]
    img = img.reshape(h // 2, 2, w // 2, 2, 3).mean(axis=(1, 3)).astype(np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {c: np.ascontiguousarray(img[..., i]) for i, c in enumerate("RGB")}
    with OpenEXR.File(header, channels) as f:
        f.write(dst)


if __name__ == "__main__":
    main(*sys.argv[1:])
