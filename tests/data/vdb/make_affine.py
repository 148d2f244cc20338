"""Make affine.vdb (and affine.json, affine.npy): a grid whose index-to-world map turns,
mirrors and shears it (an OpenVDB AffineMap), written by OpenVDB itself.

Run from the repository root with volmc's venv and the `bpy` wheel (Blender as a module,
which bundles OpenVDB's Python module):

    python tests/data/vdb/make_affine.py

Ground truth, read back with OpenVDB from the written file: affine.npy holds every voxel of
the active bounding box as OpenVDB's accessor reads it, float32 [z, y, x]; affine.json the
bbox, the transform's indexToWorld of (0, 0, 0) and of the three unit index vectors, and the
map's type name.
"""

import json
import math
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def main():
    from volmc.peers.cycles_worker import _openvdb
    vdb = _openvdb()
    g = vdb.FloatGrid(0.0)
    g.name = "density"
    # Row-vector convention (OpenVDB's): world = [i j k 1] . M. Rows: the images of the
    # index axes, then the translation. x turned 35 degrees about z, y mirrored, z sheared.
    c, s = math.cos(math.radians(35.0)), math.sin(math.radians(35.0))
    h = 0.04
    m = [[h * c, h * s, 0.0, 0.0],
         [h * s, -h * c, 0.0, 0.0],
         [0.3 * h, 0.0, 1.2 * h, 0.0],
         [0.1, -0.25, 0.05, 1.0]]
    g.transform = vdb.createLinearTransform(m)
    acc = g.getAccessor()
    n = (14, 11, 9)
    for i in range(n[0]):
        for j in range(n[1]):
            for k in range(n[2]):
                # a lopsided blob plus a ramp: every voxel differs from its mirror images
                r2 = ((i - 9.5) / 4.0) ** 2 + ((j - 3.5) / 3.0) ** 2 + ((k - 5.0) / 3.0) ** 2
                v = 2.0 * math.exp(-r2) + 0.02 * (i + 2 * j + 3 * k)
                acc.setValueOn((i + 3, j - 2, k + 1), float(np.float32(v)))
    path = os.path.join(HERE, "affine.vdb")
    vdb.write(path, grids=[g])
    back = vdb.read(path, "density")
    (x0, y0, z0), (x1, y1, z1) = back.evalActiveVoxelBoundingBox()
    acc = back.getConstAccessor()
    arr = np.array([[[acc.getValue((x, y, z)) for x in range(x0, x1 + 1)]
                     for y in range(y0, y1 + 1)] for z in range(z0, z1 + 1)], np.float32)
    np.save(os.path.join(HERE, "affine.npy"), arr)
    xf = back.transform
    info = {"bbox": [[x0, y0, z0], [x1, y1, z1]],
            "origin": list(xf.indexToWorld((0, 0, 0))),
            "axes": [list(np.subtract(xf.indexToWorld(e), xf.indexToWorld((0, 0, 0))))
                     for e in ((1, 0, 0), (0, 1, 0), (0, 0, 1))],
            "map": xf.typeName() if callable(getattr(xf, "typeName", None)) else ""}
    with open(os.path.join(HERE, "affine.json"), "w") as f:
        json.dump(info, f, indent=1)
        f.write("\n")
    print(info, arr.shape, os.path.getsize(path))


if __name__ == "__main__":
    sys.exit(main())
