"""Convert the MNI152 ICBM 2009a T1 brain template into a volmc density grid.

This is a one-time conversion tool, not part of volmc (nilearn is not a volmc
dependency).  It wrote ``scenes/data/mni152.npz`` (used by
``scenes/gallery/scan.toml``) when run, from the repository root, as

    pip install nilearn==0.14.1      # brings nibabel 5.4.2
    python scenes/data/make_mni152.py

with numpy 2.4.6.  It reads only the file that the nilearn wheel ships inside
the package (``nilearn/datasets/data/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz``,
the skull-stripped ICBM 2009a nonlinear symmetric T1 template at 1 mm, 197 x 233 x 189
voxels, RAS), through ``nilearn.datasets.load_mni152_template()``: no network.
Origin, citation and licence: ``MNI152_LICENSE.txt`` beside this script.

Steps:

1. Crop to the brain's bounding box plus a small empty margin (the template
   ends at the lowest slice, which cuts the brain stem; that slice is kept).
2. Reorient RAS to volmc's world (+y up, the camera's default view from +z,
   +x to the right): x = left (-R), y = superior, z = anterior.  That is a
   rotation, not a mirror, so the head is upright and faces +z (a camera on
   +z sees the face, the subject's left on the image's right).
3. Average 2 x 2 x 2 blocks (2 mm voxels; at most 96 per axis).
4. Transfer function on the T1 intensity (0-1): cerebrospinal fluid
   (ventricles, sulci) maps to 0, grey matter to about ``GREY``, white matter
   to 1, with smooth ramps between; the result is quantised to 1/255 (the
   source is 8-bit), which also keeps the compressed file small.

The array is saved as "density" (float32, [z, y, x]) together with
"voxel_mm" (the voxel size) and "extent_mm" (the box, x y z), which volmc
ignores; ``medium.bounds`` in the scene must be proportional to extent_mm.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

BLOCK = 2            # voxels averaged per axis: 1 mm -> 2 mm
MARGIN = 2           # empty source voxels kept around the brain (before averaging)
# Transfer function breakpoints on the normalised T1 intensity (template / 255):
# CSF lies below ~0.40, grey matter ~0.55-0.68, white matter ~0.80-0.90.
CSF_HI = 0.42        # at and below: empty
GREY_LO = 0.58       # grey matter plateau from here ...
GREY = 0.2           # ... at this density (low: a translucent cortex over the white matter)
WHITE_LO = 0.72      # white matter ramps up from here ...
WHITE_HI = 0.86      # ... to density 1 here


def _smoothstep(a, b, x):
    t = np.clip((x - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def transfer(t1):
    """Normalised T1 intensity -> density in [0, 1]."""
    grey = GREY * _smoothstep(CSF_HI, GREY_LO, t1)
    return grey + (1.0 - GREY) * _smoothstep(WHITE_LO, WHITE_HI, t1)


def load_template():
    import nibabel as nib
    import nilearn
    from nilearn.datasets import load_mni152_template

    img = load_mni152_template()            # resolution 1: the shipped file, max -> 1
    if nib.aff2axcodes(img.affine) != ("R", "A", "S"):
        raise SystemExit(f"unexpected orientation {nib.aff2axcodes(img.affine)}")
    vox = np.abs(np.diag(img.affine)[:3])
    if not np.allclose(vox, 1.0):
        raise SystemExit(f"unexpected voxel size {vox}")
    return np.asarray(img.get_fdata(), dtype=np.float64), nilearn.__version__


def convert(ras):
    """RAS volume (1 mm) -> (density [z, y, x] float32, extent_mm (x, y, z))."""
    nzv = np.argwhere(ras > 0)
    lo = np.maximum(nzv.min(0) - MARGIN, 0)
    hi = np.minimum(nzv.max(0) + 1 + MARGIN, ras.shape)
    # Round each side up to a whole number of blocks, growing the box (with zeros).
    size = -(-(hi - lo) // BLOCK) * BLOCK
    box = np.zeros(size)
    sub = ras[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
    box[:sub.shape[0], :sub.shape[1], :sub.shape[2]] = sub
    # RAS [r, a, s] -> volmc [z, y, x] = [anterior, superior, left].
    zyx = box.transpose(1, 2, 0)[:, :, ::-1]
    nz, ny, nx = (n // BLOCK for n in zyx.shape)
    avg = zyx.reshape(nz, BLOCK, ny, BLOCK, nx, BLOCK).mean(axis=(1, 3, 5))
    dens = np.round(transfer(avg) * 255.0) / 255.0
    dens = np.ascontiguousarray(dens, dtype=np.float32)
    extent = np.array([nx, ny, nz], dtype=np.float64) * BLOCK
    return dens, extent


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", type=Path,
                    default=Path(__file__).resolve().parent / "mni152.npz")
    args = ap.parse_args(argv)
    ras, version = load_template()
    dens, extent = convert(ras)
    np.savez_compressed(args.output, density=dens,
                        voxel_mm=np.float32(BLOCK), extent_mm=extent.astype(np.float32))
    nz, ny, nx = dens.shape
    half = extent / 200.0      # world unit = 100 mm, centred on the origin
    print(f"nilearn {version}: wrote {args.output} ({args.output.stat().st_size} bytes), "
          f"{nx} x {ny} x {nz} voxels (x y z) of {BLOCK} mm, "
          f"{np.mean(dens > 0):.1%} non-zero, mean {dens[dens > 0].mean():.3f}")
    print(f"medium.bounds at 100 mm per unit: [[{-half[0]:.2f}, {-half[1]:.2f}, "
          f"{-half[2]:.2f}], [{half[0]:.2f}, {half[1]:.2f}, {half[2]:.2f}]]")


if __name__ == "__main__":
    main()
