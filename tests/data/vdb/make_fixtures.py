"""Make the OpenVDB / NanoVDB test fixtures in this folder with OpenVDB itself.

How it was run (Debian 12, OpenVDB 10.0.1, NanoVDB 32.4.2), from the repository root:

    apt-get install -y python3-openvdb libnanovdb-tools libopenvdb-dev libboost-dev g++
    /usr/bin/python3 tests/data/vdb/make_fixtures.py

It needs Debian's pyopenvdb, so it runs with the system python, not volmc's venv. The
grids are written by pyopenvdb; `recompress.cpp` (compiled here against libopenvdb) re-saves
them with other compressions, since pyopenvdb always writes OpenVDB's default (blosc);
`nanovdb_convert` makes the .nvdb files. Files too large to commit uncompressed (an
uncompressed .vdb or .nvdb stores whole 32^3 upper nodes) are committed gzipped
(`*.gz`); the tests gunzip them into a temporary folder.

Ground truth, read back with OpenVDB from the written file (so half floats are the values
OpenVDB itself decodes):
  NAME.npy   float32 [z, y, x] over the grid's active-voxel bounding box: OpenVDB's
             accessor value of every voxel there (background outside leaves and tiles).
  NAME.json  bbox (imin, imax inclusive), voxel_size, the world box whose voxel centres sit
             on OpenVDB's voxel centres (OpenVDB's indexToWorld of imin - 0.5 and imax + 0.5),
             and sample voxels: index, OpenVDB's indexToWorld of it (its centre), value, active.
"""

import gzip
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np
import pyopenvdb as vdb

HERE = os.path.dirname(os.path.abspath(__file__))


def blobs(x, y, z):
    """Three Gaussian blobs (world units); density in [0, ~1.3]."""
    d = 0.0
    for (cx, cy, cz, r, a) in ((0.35, 0.50, 0.85, 0.30, 1.0), (0.70, 0.75, 0.95, 0.15, 0.6),
                               (0.10, 0.25, 0.55, 0.12, 0.8)):
        d += a * math.exp(-((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2) / r ** 2)
    return d


def fill_analytic(grid, f, lo, hi, cutoff, quantum=None):
    """Set voxels in index box [lo, hi] active with f(world centre) where f > cutoff; the
    active voxels must not touch the box's faces (else the box clipped the density)."""
    acc = grid.getAccessor()
    xf = grid.transform
    for i in range(lo[0], hi[0] + 1):
        for j in range(lo[1], hi[1] + 1):
            for k in range(lo[2], hi[2] + 1):
                v = f(*xf.indexToWorld((i, j, k)))
                if v > cutoff:
                    if quantum:  # few mantissa bits: compresses well, keeps fixtures small
                        v = round(v / quantum) * quantum
                    acc.setValueOn((i, j, k), float(np.float32(v)))
    bmin, bmax = grid.evalActiveVoxelBoundingBox()
    assert all(a < b for a, b in zip(lo, bmin)) and all(a < b for a, b in zip(bmax, hi))


def density_grid(xf, name="density", quantum=1.0 / 1024):
    g = vdb.FloatGrid(0.0)
    g.name = name
    g.gridClass = vdb.GridClass.FOG_VOLUME
    g.transform = xf
    # Index x crosses 0 (negative leaf origins); y, z stay in one upper node (each
    # upper node costs 8 KiB of masks in the file).
    fill_analytic(g, blobs, (-16, 0, 0), (28, 32, 32), 0.05, quantum)
    return g


def blobs_transform():
    xf = vdb.createLinearTransform(voxelSize=0.05)
    xf.translate((0.3, -0.2, 0.15))
    return xf  # UniformScaleTranslateMap


def truth(path, name, samples=(), dense=True):
    """Write NAME.npy (if dense) and NAME.json for grid `name` of the written file `path`."""
    g = vdb.read(path, name)
    xf = g.transform
    lo, hi = g.evalActiveVoxelBoundingBox()
    acc = g.getConstAccessor()
    base = os.path.splitext(path)[0]
    if dense:
        dense_truth(acc, lo, hi, base + ".npy")
    mid = tuple((a + b) // 2 for a, b in zip(lo, hi))
    pts = [tuple(lo), tuple(hi), mid, (lo[0], hi[1], mid[2])] + list(samples)
    info = {
        "grid": name,
        "written_by": f"OpenVDB {'.'.join(map(str, vdb.LIBRARY_VERSION))} (pyopenvdb)",
        "imin": list(lo), "imax": list(hi),
        "background": g.background,
        "voxel_size": list(xf.voxelSize()),
        "world_of_index_origin": list(xf.indexToWorld((0, 0, 0))),
        "world_bounds": [list(xf.indexToWorld(tuple(c - 0.5 for c in lo))),
                         list(xf.indexToWorld(tuple(c + 0.5 for c in hi)))],
        "samples": [{"index": list(p), "world_centre": list(xf.indexToWorld(p)),
                     "value": acc.getValue(p), "active": acc.isValueOn(p)} for p in pts],
        "active_voxels": g.activeVoxelCount(),
    }
    with open(base + ".json", "w") as f:
        json.dump(info, f, indent=1)
        f.write("\n")


def dense_truth(acc, lo, hi, path):
    shape = (hi[2] - lo[2] + 1, hi[1] - lo[1] + 1, hi[0] - lo[0] + 1)
    arr = np.empty(shape, np.float32)
    for k in range(lo[2], hi[2] + 1):
        for j in range(lo[1], hi[1] + 1):
            for i in range(lo[0], hi[0] + 1):
                arr[k - lo[2], j - lo[1], i - lo[0]] = acc.getValue((i, j, k))
    np.save(path, arr)


def out(name):
    return os.path.join(HERE, name)


def nvdb(src, dst, *flags):
    subprocess.run(["nanovdb_convert", "-f", *flags, src, dst], check=True,
                   stdout=subprocess.DEVNULL)


def gzip_to(src, dst):
    with open(src, "rb") as fi, gzip.GzipFile(dst, "wb", mtime=0) as fo:
        shutil.copyfileobj(fi, fo)


def main():
    tmp = tempfile.mkdtemp()
    recompress = os.path.join(tmp, "recompress")
    subprocess.run(["g++", "-O1", "-std=c++17", os.path.join(HERE, "recompress.cpp"), "-o",
                    recompress, "-lopenvdb", "-ltbb"], check=True)

    # blobs.vdb: float "density" and "temperature", vec3 "velocity";
    # OpenVDB's default compression (blosc + active mask).
    xf = blobs_transform()
    dens = density_grid(xf)
    temp = vdb.FloatGrid(0.0)
    temp.name = "temperature"
    temp.transform = xf
    temp.fill((0, 0, -4), (5, 6, 1), 300.0)  # inside one leaf: a leaf, not a tile
    temp.getAccessor().setValueOn((2, 3, -1), 350.5)
    vel = vdb.Vec3SGrid()
    vel.name = "velocity"
    vel.transform = xf
    vel.getAccessor().setValueOn((1, 2, 3), (1.0, 2.0, 3.0))
    vdb.write(out("blobs.vdb"), grids=[dens, temp, vel])
    truth(out("blobs.vdb"), "density", samples=[(7, 10, 7), (-1, 5, 12)])
    shutil.move(out("blobs.npy"), out("blobs_density.npy"))
    shutil.move(out("blobs.json"), out("blobs_density.json"))
    truth(out("blobs.vdb"), "temperature")
    shutil.move(out("blobs.npy"), out("blobs_temperature.npy"))
    shutil.move(out("blobs.json"), out("blobs_temperature.json"))

    # The same grids with other compressions: zip, active-mask only (values stored raw),
    # and none at all (gzipped for the repository).
    for mode, name in (("zip", "blobs_zip.vdb"), ("mask", "blobs_mask.vdb")):
        subprocess.run([recompress, mode, out("blobs.vdb"), out(name)], check=True)
    subprocess.run([recompress, "none", out("blobs.vdb"), os.path.join(tmp, "b.vdb")],
                   check=True)
    gzip_to(os.path.join(tmp, "b.vdb"), out("blobs_none.vdb.gz"))

    # NanoVDB: zip and blosc codecs, and uncompressed (gzipped for the repository).
    nvdb(out("blobs.vdb"), out("blobs_zip.nvdb"), "-z")
    nvdb(out("blobs.vdb"), out("blobs_blosc.nvdb"), "-b")
    nvdb(out("blobs.vdb"), os.path.join(tmp, "b.nvdb"))
    gzip_to(os.path.join(tmp, "b.nvdb"), out("blobs_none.nvdb.gz"))
    # NanoVDB's 16-bit quantized float grid type (Fp16): not a plain float grid.
    nvdb(out("blobs.vdb"), out("blobs_fp16.nvdb"), "-z", "--fp16", "-g", "density")

    # Half floats: unquantized values saved as 16-bit halves.
    half = vdb.FloatGrid(0.0)
    half.name = "density"
    half.transform = blobs_transform()
    fill_analytic(half, blobs, (-16, 0, 0), (28, 32, 32), 0.05)
    half.saveFloatAsHalf = True
    vdb.write(out("half.vdb"), grids=[half])
    truth(out("half.vdb"), "density")
    subprocess.run([recompress, "zip", out("half.vdb"), out("half_zip.vdb")], check=True)

    # Quirks: UniformScaleMap (no translation); an active tile (an 8^3 block filled with one
    # value becomes a tile in a lower internal node); inactive voxels inside a leaf with a
    # value other than the background; a leaf with no active voxels.
    q = vdb.FloatGrid(0.0)
    q.name = "density"
    q.transform = vdb.createLinearTransform(voxelSize=0.1)
    qa = q.getAccessor()
    for i in range(-3, 5):
        for j in range(0, 6):
            qa.setValueOn((i, j, 2), 0.125 * (i + 4) + 0.01 * j)
    qa.setValueOff((1, 1, 3), 0.5)  # inactive, non-background, in an active voxel's leaf
    qa.setValueOff((-2, 4, 5), 0.25)
    q.fill((8, 0, 0), (15, 7, 7), 0.75, active=True)  # one lower-node tile
    q.prune()
    qa = q.getAccessor()
    qa.setValueOff((40, 41, 42), 0.375)  # a leaf with no active voxel, outside the bbox
    vdb.write(out("quirks.vdb"), grids=[q])
    truth(out("quirks.vdb"), "density", samples=[(1, 1, 3), (-2, 4, 5), (40, 41, 42),
                                                 (12, 3, 5), (8, 0, 0), (15, 7, 7)])
    nvdb(out("quirks.vdb"), out("quirks.nvdb"), "-z")
    subprocess.run([recompress, "zip", out("quirks.vdb"), out("quirks_zip.vdb")], check=True)
    subprocess.run([recompress, "mask", out("quirks.vdb"), out("quirks_mask.vdb")],
                   check=True)

    # A 128^3 active tile in an upper internal node (read as 4096 blocks; its dense
    # truth is too big to commit, the JSON samples it), and a 4096^3 root-node tile
    # (2^36 voxels: refused).
    t = vdb.FloatGrid(0.0)
    t.name = "density"
    t.transform = vdb.createLinearTransform(voxelSize=0.01)
    t.fill((128, 0, 128), (255, 127, 255), 0.625)
    t.getAccessor().setValueOn((130, 130, 130), 0.875)
    t.prune()
    vdb.write(out("bigtile.vdb"), grids=[t])
    truth(out("bigtile.vdb"), "density", dense=False,
          samples=[(128, 0, 128), (255, 127, 255), (200, 64, 180), (130, 130, 130),
                   (131, 130, 130)])
    nvdb(out("bigtile.vdb"), out("bigtile.nvdb"), "-z")
    r = vdb.FloatGrid(0.0)
    r.name = "density"
    r.fill((0, 0, 0), (4095, 4095, 4095), 0.5)
    r.prune()
    vdb.write(out("roottile.vdb"), grids=[r])
    nvdb(out("roottile.vdb"), out("roottile.nvdb"), "-z")

    # Axis-aligned non-uniform scale with translation (ScaleTranslateMap): readable.
    xf = vdb.createLinearTransform(voxelSize=0.05)
    xf.scale((1.0, 0.8, 0.6))
    xf.translate((-0.1, 0.1, 0.05))
    ns = vdb.FloatGrid(0.0)
    ns.name = "density"
    ns.transform = xf
    fill_analytic(ns, blobs, (0, 0, 0), (30, 30, 60), 0.3, 1.0 / 256)
    vdb.write(out("nonuniform.vdb"), grids=[ns])
    truth(out("nonuniform.vdb"), "density")
    nvdb(out("nonuniform.vdb"), out("nonuniform.nvdb"), "-z")

    # A narrow-band level set (background 0.15, inactive voxels inside at -0.15): the
    # leaves' inactive values are stored as +/- background with a selection mask.
    ls = vdb.createLevelSetSphere(radius=0.3, center=(1.0, 1.1, 1.2), voxelSize=0.05,
                                  halfWidth=3.0)
    ls.name = "density"
    vdb.write(out("levelset.vdb"), grids=[ls])
    truth(out("levelset.vdb"), "density")
    nvdb(out("levelset.vdb"), out("levelset.nvdb"), "-z")

    # Two voxels far apart: a dense array over their bbox would hold ~1.3e9 voxels.
    sp = vdb.FloatGrid(0.0)
    sp.name = "density"
    sp.transform = vdb.createLinearTransform(voxelSize=0.001)
    sp.getAccessor().setValueOn((-500, 0, 0), 0.5)
    sp.getAccessor().setValueOn((700, 1000, 1100), 0.25)
    vdb.write(out("sparse.vdb"), grids=[sp])
    nvdb(out("sparse.vdb"), out("sparse.nvdb"), "-z")

    # Transforms volmc cannot represent: a rotation, and a negative (mirroring) scale.
    rot = vdb.FloatGrid(0.0)
    rot.name = "density"
    rot.transform = blobs_transform()
    rot.transform.rotate(math.radians(30.0), vdb.Axis.Z)
    rot.fill((0, 0, 0), (3, 4, 5), 0.5)
    vdb.write(out("rotated.vdb"), grids=[rot])
    nvdb(out("rotated.vdb"), out("rotated.nvdb"), "-z")
    neg = vdb.FloatGrid(0.0)
    neg.name = "density"
    neg.transform = vdb.createLinearTransform([[-0.05, 0, 0, 0], [0, 0.05, 0, 0],
                                               [0, 0, 0.05, 0], [0.1, 0.2, 0.3, 1]])
    neg.getAccessor().setValueOn((1, 2, 3), 1.0)
    vdb.write(out("negscale.vdb"), grids=[neg])
    nvdb(out("negscale.vdb"), out("negscale.nvdb"), "-z")

    inactive_tiles()

    shutil.rmtree(tmp)
    for name in sorted(os.listdir(HERE)):
        print(f"{os.path.getsize(out(name)):8d}  {name}")


def inactive_tiles():
    """inactive.vdb / .nvdb: inactive tiles whose value is not the background, at every
    level of the tree (eight 8^3 tiles in a lower node, a 128^3 tile in an upper node, a
    4096^3 root tile), each cut by the active bbox, whose voxels lie outside all three
    (getValue returns the tile's value there; a reader that took inactive tiles for the
    background read 0)."""
    g = vdb.FloatGrid(0.0)
    g.name = "density"
    g.transform = vdb.createLinearTransform(voxelSize=0.1)
    g.fill((0, 0, 0), (15, 15, 15), 0.6, active=False)
    g.fill((128, 0, 0), (255, 127, 127), 0.2, active=False)
    g.fill((-4096, 0, 0), (-1, 4095, 4095), 0.1, active=False)
    acc = g.getAccessor()
    for ijk, v in [((-3, -2, -1), 1.0), ((140, 10, -1), 0.25), ((-3, -2, 12), 0.5),
                   ((20, 3, 4), 0.75)]:
        acc.setValueOn(ijk, v)
    g.prune()
    # "flame", on the same lattice, active only over 2..5: its inactive 8^3 tile and its
    # inactive leaf voxel lie outside its own active box but inside the density's, so
    # placed on the density's voxels it reads them (inactive_flame.npy: getValue there).
    f = vdb.FloatGrid(0.0)
    f.name = "flame"
    f.transform = g.transform
    f.fill((2, 2, 2), (5, 5, 5), 0.5)
    f.fill((32, 0, 0), (39, 7, 7), 0.8, active=False)
    f.getAccessor().setValueOff((60, 5, 5), 0.9)
    f.prune()
    vdb.write(out("inactive.vdb"), grids=[g, f])
    lo, hi = g.evalActiveVoxelBoundingBox()
    dense_truth(vdb.read(out("inactive.vdb"), "flame").getConstAccessor(), lo, hi,
                out("inactive_flame.npy"))
    truth(out("inactive.vdb"), "density", samples=[(0, 0, 0), (15, 10, 12), (130, 5, 5),
                                                 (-1, 0, 0), (-3, 10, 12), (16, 0, 0)])
    nvdb(out("inactive.vdb"), out("inactive.nvdb"), "-z")


if __name__ == "__main__":
    # "inactive": make only the inactive-tile fixtures (added after the others were made).
    if sys.argv[1:] == ["inactive"]:
        sys.exit(inactive_tiles())
    sys.exit(main())
